"""Install rules for the scara_sim ROS 2 package."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'scara_sim'

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
    description='Simulated SCARA and URDF arms, scripted human hand and scripted demonstrator.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'scara_sim = scara_sim.scara_sim_node:main',
            'arm_sim = scara_sim.arm_sim_node:main',
            'hand_sim = scara_sim.hand_sim_node:main',
            'demonstrator = scara_sim.demonstrator_node:main',
        ],
    },
)
