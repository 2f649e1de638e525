from setuptools import find_packages, setup

package_name = 'mlkm_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: ['fastdds_loopback.xml']},  # mlkm_ros.network's DDS profile
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='mlkm team',
    maintainer_email='dev@example.com',
    description='ROS glue shared by the nodes: QoS profiles, message conversions, parameters.',
    license='Apache-2.0',
)
