from setuptools import find_packages, setup

PACKAGE = 'sagg_lab'

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
    ],
    install_requires=['setuptools'],
    # 'test': colcon runs the repository's suite with pytest from this package (setup.cfg testpaths)
    extras_require={'test': ['pytest']},
    zip_safe=True,
    maintainer='sagg developers',
    maintainer_email='sagg-dev@example.com',
    description='Measuring tools of sagg (benchmarks, soaks, figure scripts, the peer comparison): '
                'sagg bench speed/graph/riac/soak/hostile/quality and python -m sagg_lab.NAME. '
                'Never imported by the runtime.',
    license='Apache-2.0',
    entry_points={
        # `sagg bench NAME` (sagg_bringup.cli.benches.GROUP)
        'sagg.bench': [
            'speed = sagg_lab.benches:SPEED',
            'riac = sagg_lab.benches:RIAC',
            'graph = sagg_lab.benches:GRAPH',
            'soak = sagg_lab.benches:SOAK',
            'hostile = sagg_lab.benches:HOSTILE',
            'quality = sagg_lab.benches:QUALITY',
        ],
    },
)
