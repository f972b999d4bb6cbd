"""ament_python setup for dmf_sim; also installs with plain pip."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'dmf_sim'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'benchmarks']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', sorted(glob('config/*.yaml'))
         + sorted(glob('config/*.csv')) + sorted(glob('config/*.json'))),
        ('share/' + PACKAGE + '/config/profiles', sorted(glob('config/profiles/*.yaml'))),
        ('share/' + PACKAGE + '/launch', sorted(glob('launch/*.launch.py'))),
    ],
    python_requires='>=3.11',
    # Minimums are the ROS 2 Jazzy platform's versions (Ubuntu 24.04, what rosdep installs for
    # package.xml's keys); constraints/platform-jazzy.txt pins them and `make test-platform`
    # runs the suite on them.
    install_requires=[
        'setuptools',
        'numpy>=1.26',
        'scipy>=1.11',
        'PyYAML>=6',
        'matplotlib>=3.6',
        'numba>=0.59',                 # the first with Python 3.12 (Ubuntu 24.04 has no apt numba)
        'tqdm>=4.66',
        'rosbags>=0.10',
        'mcap>=1.1',
        'rich>=13',
        'foxglove-sdk>=0.30',
        'dask[distributed]>=2024.1',   # dmf-sim design: a LocalCluster or a real cluster
        'pyarrow>=14',                 # dmf-sim design: the Parquet result table
        'fatpack>=0.7',                # dmf-sim durability: rainflow cycles
        'threadpoolctl>=3',            # dmf-sim run: BLAS in one thread for the small products
        'optuna>=5.0',                 # dmf-sim optimize: NSGA-II / TPE, journal storage
        'zlib-ng>=0.4',                # bags: the chunks' CRC-32, ~4.7x faster than zlib's
    ],
    extras_require={
        'ros': ['ros-jazzy-rclpy[fastrtps]', 'ros-jazzy-common-interfaces'],
        'test': ['pytest>=7', 'mcap-ros2-support>=0.5', 'websockets>=10.4', 'ruff>=0.5',
                 'import-linter>=2.1',
                 'sphinx>=7.2', 'myst-parser>=2'],   # make docs (run by make test)
    },
    zip_safe=True,
    maintainer='dmf_sim developers',
    maintainer_email='dmf-sim@example.com',
    description='Truck driveline torsional vibrations with a two-step dual mass flywheel',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'dmf-sim = dmf_sim.cli:main',
            'driveline_node = dmf_sim.node:main',
        ],
    },
)
