from setuptools import find_packages, setup

PACKAGE = 'sagg_sim_bridge'

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
    description='MuJoCo models (N-DOF arms, quadruped, fishing rod), simulators and the bridge node '
                'speaking the ros2_control-style hardware contract.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'mujoco_bridge = sagg_sim_bridge.node:main',
            'synergy_bridge = sagg_sim_bridge.synergy_node:main',
        ],
    },
)
