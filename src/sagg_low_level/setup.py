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


def kernel(name: str, opt: str = '-O2') -> Extension:
    """One of the package's compiled kernels (sagg_low_level/<name>.c; plain C99 against the CPython
    API, no numpy headers). -ffp-contract=off: no fused multiply-add, so that their floats are the
    canonical ones numpy computes (the searches' distances are memory_distance's, bit for bit);
    -fno-fast-math: no reassociation, so vectorised loops keep each sum's order."""
    return Extension(
        PACKAGE + '.' + name,
        sources=[PACKAGE + '/' + name + '.c'],
        include_dirs=[COMMON_INCLUDE],
        depends=[os.path.join(COMMON_INCLUDE, 'sagg_kernel_buffers.h')],
        extra_compile_args=[opt, '-std=c99', '-ffp-contract=off', '-fno-fast-math'],
    )


# knn_kernel: the neighbour searches' inner loops (-O3: the distance and box-bound loops over runs
# of points vectorise; the answers are the same, test_knn_kernel); reach_kernel:
# the local model's small linear algebra (least-squares Jacobians, pseudo-inverse / damped /
# clamped reaching steps)
KERNELS = [kernel('knn_kernel', '-O3'), kernel('reach_kernel')]

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=DATA_FILES,
    install_requires=['setuptools'],
    ext_modules=KERNELS,
    zip_safe=False,
    maintainer='sagg developers',
    maintainer_email='sagg-dev@example.com',
    description='SAGG-RIAC low level: sample memory, local inverse models, reacher, synergy optimiser, '
                'actuator babbling, and the learner node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'learner = sagg_low_level.node:main',
            'model_server = sagg_low_level.model_server:main',
            'fixed_learner = sagg_low_level.fixed_node:main',
            # the old name of fixed_learner, kept as an alias for one release
            'synergy_learner = sagg_low_level.fixed_node:main',
        ],
    },
)
