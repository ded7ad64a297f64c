"""Install rules for the hri_adaptive_controller ROS 2 package."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'hri_adaptive_controller'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/tasks', glob('tasks/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='HRI demo maintainers',
    maintainer_email='maintainers@hri-demo.example.org',
    description='Event-based task switching and the adaptive HRI torque controller.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'event_manager = hri_adaptive_controller.event_manager_node:main',
            'controller = hri_adaptive_controller.controller_node:main',
            'event_detector = hri_adaptive_controller.event_detector_node:main',
        ],
    },
)
