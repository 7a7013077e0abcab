import os

from setuptools import Extension, find_packages, setup

PACKAGE = 'sagg_low_level'
# the kernels' shared buffer helpers (a build-time header of sagg_common; realpath: the source tree,
# also when a build folder links to this file)
COMMON_INCLUDE = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'sagg_common', 'include')

# ament_python layout: the resource marker makes the package visible in the ament index, and
# package.xml goes to share/<pkg>, so that `ros2 run`/`ros2 launch` work on a full ROS 2 install.
DATA_FILES = [
    ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
    ('share/' + PACKAGE, ['package.xml']),
]

# The neighbour searches' inner loops, compiled (sagg_low_level/knn_kernel.c; plain C99 against
# the CPython API, no numpy headers). -ffp-contract=off: no fused multiply-add, so its
# distances are the canonical ones numpy computes (memory_distance), bit for bit.
KNN_KERNEL = Extension(
    PACKAGE + '.knn_kernel',
    sources=[PACKAGE + '/knn_kernel.c'],
    include_dirs=[COMMON_INCLUDE],
    depends=[os.path.join(COMMON_INCLUDE, 'sagg_kernel_buffers.h')],
    extra_compile_args=['-O2', '-std=c99', '-ffp-contract=off', '-fno-fast-math'],
)
# The local model's small linear algebra (sagg_low_level/reach_kernel.c: least-squares Jacobians,
# pseudo-inverse / damped / clamped reaching steps), same flags.
REACH_KERNEL = Extension(
    PACKAGE + '.reach_kernel',
    sources=[PACKAGE + '/reach_kernel.c'],
    include_dirs=[COMMON_INCLUDE],
    depends=[os.path.join(COMMON_INCLUDE, 'sagg_kernel_buffers.h')],
    extra_compile_args=['-O2', '-std=c99', '-ffp-contract=off', '-fno-fast-math'],
)

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=DATA_FILES,
    install_requires=['setuptools'],
    ext_modules=[KNN_KERNEL, REACH_KERNEL],
    zip_safe=False,
    maintainer='sagg developers',
    maintainer_email='sagg-dev@example.com',
    description='SAGG-RIAC low level: sample memory, local inverse models, reacher, synergy optimiser, actuator babbling, and the learner node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'learner = sagg_low_level.node:main',
            'fixed_learner = sagg_low_level.fixed_node:main',
            # the old name of fixed_learner, kept as an alias for one release (issue 26)
            'synergy_learner = sagg_low_level.fixed_node:main',
        ],
    },
)
