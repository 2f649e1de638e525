from glob import glob

from setuptools import find_packages, setup

package_name = 'rosbag_mcap'

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
    description='Record, replay and reindex rosbag2-compatible MCAP bags.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'bag_recorder = rosbag_mcap.entry:bag_recorder',
            'bag_player = rosbag_mcap.entry:bag_player',
            'bag_reindex = rosbag_mcap.reindex:main',
        ],
    },
)
