"""ccf_ros: ament_python package that also installs with plain pip (no ROS install needed)."""

import os
from glob import glob

from setuptools import find_packages, setup

package_name = 'ccf_ros'

requires = [
    'setuptools',
    'numpy>=1.24',
    'rosbags>=0.10.4,<0.12',
    'tqdm>=4.60',
    'matplotlib>=3.6',
    'pyyaml>=6',
]
# In a sourced ROS workspace (colcon build) rclpy and the messages come from the ROS install; from pip they come
# as the Jazzy wheels. A pip install sets no AMENT_PREFIX_PATH.
if not os.environ.get('AMENT_PREFIX_PATH'):
    requires += ['ros-jazzy-rclpy[fastrtps]', 'ros-jazzy-common-interfaces']

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'benchmarks', 'experiments', 'checks']),
    # PEP 561: the package's type hints count for its users.
    package_data={'ccf_ros': ['py.typed']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.py')),
    ],
    install_requires=requires,
    extras_require={
        # `ccf study`'s least-squares gain fit (LSCF); everything else needs only numpy.
        'study': ['scipy>=1.10'],
        # `ccf fleet`: many bags on a local or an existing Dask cluster (tqdm and matplotlib are required anyway).
        'fleet': ['dask[distributed]>=2024.1'],
        'test': ['dask[distributed]>=2024.1', 'pytest>=7', 'ruff>=0.5', 'mypy>=1.8', 'colcon-core', 'colcon-ros', 'colcon-python-setup-py', 'scipy>=1.10'],
    },
    python_requires='>=3.11',
    zip_safe=True,
    maintainer='ccf_ros developers',
    maintainer_email='dev@ccf-ros.local',
    description='IMU orientation with a cascaded complementary filter: ROS 2 node and offline bag tools',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'ccf = ccf_ros.cli:main',
            'ccf_node = ccf_ros.node:main',
            # ccf_node as a managed node (rclpy.lifecycle): unconfigured until configured and activated.
            'ccf_lifecycle_node = ccf_ros.node:lifecycle_main',
            # imu_tools drop-ins: `package='ccf_ros'` in a launch file written for imu_filter_madgwick or
            # imu_complementary_filter, nothing else changed (ccf_ros/compat.py).
            'imu_filter_madgwick_node = ccf_ros.node:imu_filter_madgwick_main',
            'complementary_filter_node = ccf_ros.node:complementary_filter_main',
        ],
    },
)
