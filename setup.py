"""Packaging for rigidrot_ros: an ament_python package that also installs from pip."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'rigidrot_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', sorted(glob('config/*.yaml'))),
    ],
    python_requires='>=3.10',
    install_requires=[
        'setuptools',
        'numpy>=1.24',
        'mpmath>=1.3',
        'python-flint>=0.6',
        'numba>=0.60',
        'PyYAML>=6',
        'mcap>=1.2',
        'mcap-ros2-support>=0.5',
        'zstandard',
        'ros-jazzy-rclpy[fastrtps]',
        'ros-jazzy-common-interfaces',
    ],
    extras_require={
        'plot': ['matplotlib>=3.7'],
        'estimator': ['ahrs>=0.3'],
        'campaign': ['dask[distributed]>=2023.1', 'cryptography>=3.1', 'matplotlib>=3.7',
                     'scipy>=1.10'],
        'docs': ['sphinx>=7.2', 'myst-parser>=2'],
        'bench': ['scipy>=1.10', 'matplotlib>=3.7', 'rosbags>=0.10'],
        'test': [
            'pytest>=7',
            'rosbags>=0.10',
            'ahrs>=0.3',
            'allantools>=2019.9',
            'evo>=1.20',
            'matplotlib>=3.7',
            'scipy>=1.10',
            'flake8>=7',
            'flake8-quotes>=3.4',
            'flake8-import-order>=0.18',
            'pydocstyle>=6.3',
            'colcon-core',
            'colcon-ros',
            'colcon-python-setup-py',
            'colcon-package-information',
            'colcon-library-path',
            'ros-jazzy-ament-package',
            'sphinx>=7.2',
            'myst-parser>=2',
            'dask[distributed]>=2023.1',
            'cryptography>=3.1',
        ],
    },
    zip_safe=True,
    maintainer='rigidrot_ros maintainers',
    maintainer_email='maintainers@rigidrot.invalid',
    description='Exact analytic attitude of a rotating rigid body, for ROS 2.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'attitude_node = rigidrot_ros.ros.attitude_node:main',
            'rigidrot_echo = rigidrot_ros.tools.echo:main',
            'rigidrot_compare = rigidrot_ros.tools.compare:main',
            'rigidrot_replay = rigidrot_ros.tools.replay:main',
            'rigidrot_demo_estimator = rigidrot_ros.tools.demo_estimator:main',
            'rigidrot_record = rigidrot_ros.tools.record:main',
            'rigidrot_reindex = rigidrot_ros.tools.reindex:main',
            'rigidrot_bench = rigidrot_ros.bench.run:main',
            'rigidrot_generate = rigidrot_ros.tools.generate:main',
            'rigidrot_mekf = rigidrot_ros.estimators.mekf_node:main',
            'rigidrot_campaign = rigidrot_ros.tools.campaign:main',
        ],
    },
)
