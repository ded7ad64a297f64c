"""Install rules for the hri_core ROS 2 package (a library: no executables)."""

from setuptools import find_packages, setup

package_name = 'hri_core'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='HRI demo maintainers',
    maintainer_email='maintainers@hri-demo.example.org',
    description='Shared SCARA model, task potential and files, and ROS helpers of the HRI suite.',
    license='Apache-2.0',
)
