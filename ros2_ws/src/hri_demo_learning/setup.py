"""Install rules for the hri_demo_learning ROS 2 package."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'hri_demo_learning'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='HRI demo maintainers',
    maintainer_email='maintainers@hri-demo.example.org',
    description='Learning HRI tasks from demonstration: rosbag2 recorder and learner.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'recorder = hri_demo_learning.recorder_node:main',
            'learner = hri_demo_learning.learner_node:main',
        ],
    },
)
