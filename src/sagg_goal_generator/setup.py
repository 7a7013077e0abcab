import os

from setuptools import Extension, find_packages, setup

PACKAGE = 'sagg_goal_generator'
# the kernels' shared buffer helpers (a build-time header of sagg_common; realpath: the source tree,
# also when a build folder links to this file)
COMMON_INCLUDE = os.path.join(os.path.dirname(os.path.realpath(__file__)), '..', 'sagg_common', 'include')

# ament_python layout: the resource marker makes the package visible in the ament index, and
# package.xml goes to share/<pkg>, so that `ros2 run`/`ros2 launch` work on a full ROS 2 install.
DATA_FILES = [
    ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
    ('share/' + PACKAGE, ['package.xml']),
]

# The alp-gmm teacher's EM, compiled (sagg_goal_generator/em_kernel.c; plain C99 against the
# CPython API, no numpy headers).
EM_KERNEL = Extension(
    PACKAGE + '.em_kernel',
    sources=[PACKAGE + '/em_kernel.c'],
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
    ext_modules=[EM_KERNEL],
    zip_safe=False,
    maintainer='sagg developers',
    maintainer_email='sagg-dev@example.com',
    description='SAGG-RIAC high level: competence, region tree with interest, splits and goal selection, '
                'and its ROS 2 node.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': [
            'goal_generator = sagg_goal_generator.node:main',
        ],
    },
)
