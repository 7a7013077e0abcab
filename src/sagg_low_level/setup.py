from setuptools import find_packages, setup

PACKAGE = 'sagg_low_level'

# ament_python layout: the resource marker makes the package visible in the ament index, and
# package.xml goes to share/<pkg>, so that `ros2 run`/`ros2 launch` work on a full ROS 2 install.
DATA_FILES = [
    ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
    ('share/' + PACKAGE, ['package.xml']),
]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=DATA_FILES,
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='sagg developers',
    maintainer_email='sagg-dev@example.com',
    description='SAGG-RIAC low level: sample memory, local inverse models, reacher, synergy optimiser, actuator babbling, and the learner node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'learner = sagg_low_level.node:main',
            'synergy_learner = sagg_low_level.synergy_node:main',
        ],
    },
)
