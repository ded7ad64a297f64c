"""Install rules for the hri_bringup ROS 2 package."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'hri_bringup'

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
    description='Process orchestration of the HRI nodes, the `system` node (live loop '
                'from one YAML file) and the `live_view` node (the system in Foxglove).',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'system = hri_bringup.system:main',
            'live_view = hri_bringup.live_view_node:main',
        ],
    },
)
