"""ament_python setup for dmf_sim; also installs with plain pip."""
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'dmf_sim'

# The features whose libraries the rest of the package does not need: an extra each
# (dmf_sim/core/optional.py imports them and names the extra when one is missing); `make`
# installs [all]. pyarrow < 26: pyarrow 26 refuses to import with numpy < 2 ("pyarrow requires
# NumPy 2.0 or newer") but does not declare numpy, so pip would pick it next to the ROS 2 Jazzy
# platform's numpy 1.26 (constraints/platform-jazzy.txt); environment markers cannot see the
# installed numpy, so the bound is an upper one. 25.0.1 imports with numpy 1.26 and 2.x alike.
DASK = 'dask[distributed]>=2024.1'
PYARROW = 'pyarrow>=14,<26'
EXTRAS = {
    'design': [DASK, PYARROW],                  # dmf-sim design: Dask, the Parquet table
    'optimize': [DASK, PYARROW, 'optuna>=5.0'],  # dmf-sim optimize: NSGA-II / TPE, journal
    'durability': ['fatpack>=0.7'],             # dmf-sim durability: rainflow cycles
    'foxglove': ['foxglove-sdk>=0.30'],         # the node's Foxglove server (foxglove_port)
}
EXTRAS['all'] = sorted({req for reqs in EXTRAS.values() for req in reqs})

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'benchmarks']),
    package_data={PACKAGE: ['py.typed']},     # PEP 561: type checkers read the inline types
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
        # < 2: the bag writer's block path uses the mcap writer's private state (present 1.1
        # to 1.6; dmf_sim/bags/mcap_internals.py, checked by test/bags/test_mcap_internals.py)
        'mcap>=1.1,<2',
        'rich>=13',
        'threadpoolctl>=3',            # dmf-sim run: BLAS in one thread for the small products
        'zlib-ng>=0.4',                # bags: the chunks' CRC-32, ~4.7x faster than zlib's
    ],
    extras_require={
        **EXTRAS,
        'ros': ['ros-jazzy-rclpy[fastrtps]', 'ros-jazzy-common-interfaces'],
        # the suite tests every feature, so the test extra has the feature extras' libraries
        'test': ['pytest>=7', 'mcap-ros2-support>=0.5', 'websockets>=10.4', 'ruff>=0.5',
                 'import-linter>=2.1',
                 'sphinx>=7.2', 'myst-parser>=2'] + EXTRAS['all'],   # sphinx: make docs
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
