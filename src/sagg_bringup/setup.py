import os
from glob import glob

from setuptools import find_packages, setup

PACKAGE = 'sagg_bringup'

# ament_python layout: the resource marker makes the package visible in the ament index, and
# package.xml goes to share/<pkg>, so that `ros2 run`/`ros2 launch` work on a full ROS 2 install.
DATA_FILES = [
    ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
    ('share/' + PACKAGE, ['package.xml']),
]

# realpath: colcon may run a symlinked copy of this file from its build folder.
HERE = os.path.dirname(os.path.realpath(__file__))


def _rel(paths):
    # data_files sources are read relative to the current directory; keep them relative (wheels
    # reject absolute source paths) whatever directory setup.py is run from.
    return sorted(os.path.relpath(p) for p in paths)


# Launch files (full ROS installs: `ros2 launch sagg_bringup <file>`), when present.
launch_files = _rel(glob(os.path.join(HERE, 'launch', '*.py')))
if launch_files:
    DATA_FILES.append(('share/' + PACKAGE + '/launch', launch_files))
# The repository's experiment configs (config/*.yaml at the repo root), when present.
config_files = _rel(glob(os.path.join(HERE, '..', '..', 'config', '*.yaml')))
if config_files:
    DATA_FILES.append(('share/' + PACKAGE + '/config', config_files))
# The robot model files those configs name (arm.model is relative to the config's directory, so an
# installed config finds its model beside it: share/sagg_bringup/config/robots/).
robot_files = _rel(p for p in glob(os.path.join(HERE, '..', '..', 'config', 'robots', '*')) if os.path.isfile(p))
if robot_files:
    DATA_FILES.append(('share/' + PACKAGE + '/config/robots', robot_files))

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    package_data={PACKAGE + '.experiments': ['claims.yaml']},  # `sagg reproduce`'s claim registry
    data_files=DATA_FILES,
    install_requires=['setuptools'],
    # Optional: `sagg bench compare --ray` (pinned with its dependencies in requirements-ray.txt).
    extras_require={'ray': ['ray==2.60.0']},
    zip_safe=True,
    maintainer='sagg developers',
    maintainer_email='sagg-dev@example.com',
    description='The sagg command (run, record, replay, evaluate, bench, report) and launch files '
                'for full ROS 2 installs.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'sagg = sagg_bringup.cli.cli:main',
        ],
    },
)
