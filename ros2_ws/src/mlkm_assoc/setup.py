from glob import glob

from setuptools import find_packages, setup

package_name = 'mlkm_assoc'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.param.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='mlkm team',
    maintainer_email='dev@example.com',
    description='Live MLKM association and scoring nodes; the mlkm CLI entry point.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'association_node = mlkm_assoc.entry:association_node',
            'scorer_node = mlkm_assoc.entry:scorer_node',
            'mlkm = mlkm_assoc.cli:main',
        ],
    },
)
