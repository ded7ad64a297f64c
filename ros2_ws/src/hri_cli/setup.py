"""Install rules for the hri_cli ROS 2 package (a library: scripts/bin/ros2 runs it)."""

from setuptools import find_packages, setup

package_name = 'hri_cli'

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
    description="The project's stand-in for ros2cli where only the PyPI wheels are installed: "
                '`ros2 run`, `ros2 topic` (list, info, echo, hz, pub) and `ros2 bag` '
                '(info, play).',
    license='Apache-2.0',
)
