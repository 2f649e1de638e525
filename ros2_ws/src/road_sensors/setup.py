from glob import glob

from setuptools import find_packages, setup

package_name = 'road_sensors'

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
    description='Road-side sensor sources: sensor_sim and sumo_sensors (SUMO).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sensor_sim = road_sensors.entry:sensor_sim',
            'sumo_sensors = road_sensors.entry:sumo_sensors',
        ],
    },
)
