"""Checks of the project set-up: the sagg_msgs interfaces built and installed, and the console
scripts of the Python packages.

Either installation: the project venv (`make test`: sagg_msgs built with cmake and installed into
the venv prefix, the Python packages installed editable, console scripts in the venv's bin) or a
colcon workspace (`colcon test`: each package in its own prefix of install/, console scripts in
lib/<package>, the ament index on AMENT_PREFIX_PATH).
"""
import array
import importlib
import importlib.metadata
import math
import os
import struct
import sys
from pathlib import Path

import pytest
from rclpy.serialization import deserialize_message, serialize_message

from builtin_interfaces.msg import Time
from sagg_msgs.msg import (
    CompetenceReport,
    Evaluation,
    Goal,
    LearnerStatus,
    Region,
    RegionTree,
    Sample,
)
from sagg_msgs.srv import NextGoal
from std_msgs.msg import Header

REPO = Path(__file__).resolve().parents[1]
U64_MAX = 2**64 - 1
U32_MAX = 2**32 - 1


def _f(bits):
    """float64 with the given IEEE-754 bit pattern."""
    return struct.unpack('<d', struct.pack('<Q', bits))[0]


def _bits(x):
    return struct.unpack('<Q', struct.pack('<d', x))[0]


# Values whose exact bits must survive CDR: a NaN with a payload, the sign of zero, the smallest
# subnormal, infinities, a sum that is not 0.3, and the largest finite double.
NAN_PAYLOAD = _f(0x7FF8_0000_0000_1234)
TRICKY = [NAN_PAYLOAD, -0.0, 0.1 + 0.2, _f(1), math.inf, -math.inf, 1.7976931348623157e308, -1e-300]


def _header(frame='task_space', sec=1_700_000_000, nanosec=999_999_999):
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame)


def _same(a, b, path='msg'):
    """Recursive equality of message field values; floats compared bit for bit."""
    if isinstance(a, float) or isinstance(b, float):
        assert isinstance(a, float) and isinstance(b, float), path
        assert _bits(a) == _bits(b), f'{path}: {a!r} ({_bits(a):#018x}) != {b!r} ({_bits(b):#018x})'
    elif isinstance(a, (list, tuple, array.array)):
        assert len(a) == len(b), f'{path}: length {len(a)} != {len(b)}'
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f'{path}[{i}]')
    elif hasattr(a, 'get_fields_and_field_types'):
        assert type(a) is type(b), path
        for name in a.get_fields_and_field_types():
            _same(getattr(a, name), getattr(b, name), f'{path}.{name}')
    else:
        assert a == b, f'{path}: {a!r} != {b!r}'


def _roundtrip(msg):
    data = serialize_message(msg)
    back = deserialize_message(data, type(msg))
    _same(msg, back, type(msg).__name__)
    return data, back


def _region(i):
    return Region(id=i, lower=[0.0, -150.0], upper=[75.0, 0.1 + 0.2], interest=_f(0x7FF8_0000_0000_00AB),
                  count=U32_MAX - i, mean_competence=-0.0)


MESSAGES = {
    'Goal': lambda: Goal(header=_header(), seq=U64_MAX, after_report=U64_MAX - 1,
                         mode=Goal.MODE_LOW_COMPETENCE, position=TRICKY),
    'CompetenceReport': lambda: CompetenceReport(
        header=_header(), seq=1, goal_seq=U64_MAX, kind=CompetenceReport.KIND_EXPLORATION,
        target=[], reached=TRICKY, start=list(reversed(TRICKY)), competence=NAN_PAYLOAD,
        micro_actions=123_456_789_012),
    'Region': lambda: _region(7),
    'RegionTree': lambda: RegionTree(header=_header(), goals=10, reports=U64_MAX, splits=U32_MAX,
                                     regions=[_region(1), _region(2), _region(3)]),
    'Sample': lambda: Sample(header=_header(), index=0, alpha=TRICKY[:4], delta_alpha=TRICKY[4:],
                             delta_y=[0.1 + 0.2, -0.0]),
    'LearnerStatus': lambda: LearnerStatus(
        header=_header(frame=''), strategy='SAGG-RIAC', micro_actions=30_000, goals=U64_MAX,
        samples=29_999, reports=41_234, last_competence=-0.0, micro_actions_per_second=0.1 + 0.2, paused=True,
        pause_reason='waiting for /joint_states \u00e9'),
    'Evaluation': lambda: Evaluation(header=_header(), micro_actions=U64_MAX, mean_error=0.1 + 0.2,
                                     median_error=NAN_PAYLOAD, errors=TRICKY * 3),
}


@pytest.mark.parametrize('name', sorted(MESSAGES))
def test_message_roundtrip_is_exact(name):
    msg = MESSAGES[name]()
    data, back = _roundtrip(msg)
    # A default-constructed message serialises differently: the values really travelled.
    assert serialize_message(type(msg)()) != data
    if name == 'Goal':
        assert back.mode == Goal.MODE_LOW_COMPETENCE and back.seq == U64_MAX
        assert math.isnan(back.position[0]) and _bits(back.position[0]) == 0x7FF8_0000_0000_1234
        assert back.position[2] == 0.1 + 0.2 and back.position[2] != 0.3
        assert math.copysign(1.0, back.position[1]) == -1.0
    if name == 'RegionTree':
        assert [r.id for r in back.regions] == [1, 2, 3]
        assert back.regions[0].count == U32_MAX - 1
    if name == 'LearnerStatus':
        assert back.pause_reason.endswith('\u00e9') and back.paused is True


def test_default_messages_roundtrip():
    for cls in (Goal, CompetenceReport, Region, RegionTree, Sample, LearnerStatus, Evaluation,
                NextGoal.Request, NextGoal.Response):
        _roundtrip(cls())


def test_next_goal_service_roundtrip():
    req = NextGoal.Request(after_report=U64_MAX)
    _, back = _roundtrip(req)
    assert back.after_report == U64_MAX
    resp = NextGoal.Response(goal=MESSAGES['Goal']())
    _, back = _roundtrip(resp)
    assert back.goal.after_report == U64_MAX - 1
    assert NextGoal.Request.get_fields_and_field_types() == {'after_report': 'uint64'}
    assert NextGoal.Response.get_fields_and_field_types() == {'goal': 'sagg_msgs/Goal'}


def test_compute_ik_service_and_reach_result_fields():
    from sagg_msgs.action import Reach
    from sagg_msgs.srv import ComputeIK
    assert ComputeIK.Request.get_fields_and_field_types() == {
        'target': 'sequence<double>', 'start': 'sequence<double>', 'start_point': 'sequence<double>',
        'tolerance': 'double', 'max_steps': 'uint32'}
    assert ComputeIK.Response.get_fields_and_field_types() == {
        'success': 'boolean', 'message': 'string', 'joint_names': 'sequence<string>', 'joints': 'sequence<double>',
        'predicted': 'sequence<double>', 'predicted_error': 'double', 'nearest_sample': 'double',
        'steps': 'uint32', 'outcome': 'string'}
    assert Reach.Result.get_fields_and_field_types() == {
        'reached': 'sequence<double>', 'error': 'double', 'steps': 'uint32', 'outcome': 'string',
        'joint_names': 'sequence<string>', 'joints': 'sequence<double>'}
    for cls in (ComputeIK.Request, ComputeIK.Response, Reach.Result):
        _roundtrip(cls())


def test_field_types():
    assert Goal.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'seq': 'uint64', 'after_report': 'uint64', 'mode': 'uint8',
        'position': 'sequence<double>'}
    assert CompetenceReport.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'seq': 'uint64', 'goal_seq': 'uint64', 'kind': 'uint8',
        'target': 'sequence<double>', 'reached': 'sequence<double>', 'start': 'sequence<double>',
        'competence': 'double', 'micro_actions': 'uint64'}
    assert Region.get_fields_and_field_types() == {
        'id': 'uint32', 'lower': 'sequence<double>', 'upper': 'sequence<double>',
        'interest': 'double', 'count': 'uint32', 'mean_competence': 'double'}
    assert RegionTree.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'goals': 'uint64', 'reports': 'uint64', 'splits': 'uint32',
        'regions': 'sequence<sagg_msgs/Region>'}
    assert Sample.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'index': 'uint64', 'alpha': 'sequence<double>',
        'delta_alpha': 'sequence<double>', 'delta_y': 'sequence<double>'}
    assert LearnerStatus.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'strategy': 'string', 'micro_actions': 'uint64',
        'goals': 'uint64', 'samples': 'uint64', 'reports': 'uint64', 'last_competence': 'double',
        'micro_actions_per_second': 'double', 'paused': 'boolean', 'pause_reason': 'string', 'refused': 'string',
        'prior_samples': 'uint64', 'prior_superseded': 'uint64'}
    assert Evaluation.get_fields_and_field_types() == {
        'header': 'std_msgs/Header', 'micro_actions': 'uint64', 'mean_error': 'double',
        'median_error': 'double', 'errors': 'sequence<double>'}


def test_constants():
    assert (Goal.MODE_INITIAL, Goal.MODE_REGION, Goal.MODE_GLOBAL, Goal.MODE_LOW_COMPETENCE,
            Goal.MODE_RANDOM) == (0, 1, 2, 3, 4)
    assert (CompetenceReport.KIND_GOAL, CompetenceReport.KIND_SUBGOAL,
            CompetenceReport.KIND_REACHED, CompetenceReport.KIND_EXPLORATION) == (0, 1, 2, 3)


def test_python_constants_match_the_messages():
    """The ROS-free copies of the message constants (sagg_common.report_kinds, the goal modes of
    sagg_goal_generator.core) have the values of sagg_msgs' constants, name for name."""
    from sagg_common import report_kinds
    from sagg_goal_generator import core

    for name in ("KIND_GOAL", "KIND_SUBGOAL", "KIND_REACHED", "KIND_EXPLORATION"):
        assert getattr(report_kinds, name) == getattr(CompetenceReport, name)
    assert set(report_kinds.KIND_NAMES) == {0, 1, 2, 3}
    for name in ("MODE_INITIAL", "MODE_REGION", "MODE_GLOBAL", "MODE_LOW_COMPETENCE", "MODE_RANDOM"):
        assert getattr(core, name) == getattr(Goal, name)


def msgs_prefix() -> Path:
    """The install prefix of sagg_msgs: the first of AMENT_PREFIX_PATH (a sourced workspace), then
    this Python's prefix (the venv), whose ament index lists the package."""
    prefixes = [Path(p) for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    for prefix in prefixes + [Path(sys.prefix)]:
        if (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'sagg_msgs').is_file():
            return prefix
    pytest.fail(f"sagg_msgs is in no ament index of {[str(p) for p in prefixes + [Path(sys.prefix)]]}: "
                "run `make msgs` (or `colcon build` and source the workspace)")


def test_interface_definitions_installed():
    # The .msg/.srv texts are installed next to the generated code (share/sagg_msgs), where
    # tools such as rosbags can read them; they must match the sources in the repo.
    prefix = msgs_prefix()
    share = prefix / 'share' / 'sagg_msgs'
    for sub, ext in (('msg', '.msg'), ('srv', '.srv')):
        sources = sorted((REPO / 'src' / 'sagg_msgs' / sub).glob('*' + ext))
        assert sources, f'no {ext} files in src/sagg_msgs/{sub}'
        for src in sources:
            installed = share / sub / src.name
            assert installed.is_file(), f'{installed} missing: run `make msgs`'
            assert installed.read_text() == src.read_text(), f'{installed} is stale: run `make msgs`'
    index = prefix / 'share' / 'ament_index' / 'resource_index'
    assert (index / 'packages' / 'sagg_msgs').is_file()
    assert 'msg/Goal.msg' in (index / 'rosidl_interfaces' / 'sagg_msgs').read_text()


CONSOLE_SCRIPTS = {
    'goal_generator': ('sagg_goal_generator', 'sagg_goal_generator.node:main'),
    'learner': ('sagg_low_level', 'sagg_low_level.node:main'),
    'model_server': ('sagg_low_level', 'sagg_low_level.model_server:main'),
    'mujoco_bridge': ('sagg_sim_bridge', 'sagg_sim_bridge.node:main'),
    'sagg': ('sagg_bringup', 'sagg_bringup.cli.cli:main'),
    'fixed_learner': ('sagg_low_level', 'sagg_low_level.fixed_node:main'),
    # the old name of fixed_learner, an alias for one release
    'synergy_learner': ('sagg_low_level', 'sagg_low_level.fixed_node:main'),
    'synergy_bridge': ('sagg_sim_bridge', 'sagg_sim_bridge.synergy_node:main'),
}


@pytest.mark.parametrize('script', sorted(CONSOLE_SCRIPTS))
def test_console_script_installed(script):
    # where `sagg run` and `ros2 run` look: the venv's bin (pip) or lib/<package> (colcon)
    from installed import executable
    dist, target = CONSOLE_SCRIPTS[script]
    path = Path(executable(script))
    assert os.access(path, os.X_OK)
    module, func = target.split(':')
    text = path.read_text()
    # pip writes the import; setuptools' develop/install scripts (colcon) load the entry point by name
    assert f'from {module} import {func}' in text or f"'{script}'" in text, text
    assert text.splitlines()[0].startswith('#!') and 'python' in text.splitlines()[0]
    eps = {ep.name: ep.value for ep in importlib.metadata.distribution(dist).entry_points
           if ep.group == 'console_scripts'}
    assert eps == {name: t for name, (d, t) in CONSOLE_SCRIPTS.items() if d == dist}


def test_common_has_no_console_scripts():
    eps = [ep for ep in importlib.metadata.distribution('sagg_common').entry_points
           if ep.group == 'console_scripts']
    assert eps == []


def test_the_imported_packages_are_this_checkouts_code():
    # `pip install -e` (make), `colcon build --symlink-install` or a copying install: every module
    # of the imported packages is this checkout's source, byte for byte
    import json
    for dist in ('sagg_common', 'sagg_goal_generator', 'sagg_low_level', 'sagg_sim_bridge',
                 'sagg_bringup', 'sagg_lab'):
        package = Path(importlib.import_module(dist).__file__).parent
        source = REPO / 'src' / dist / dist
        modules = sorted(f.relative_to(source) for f in source.rglob('*.py'))
        assert modules, source
        for rel in modules:
            assert (package / rel).read_bytes() == (source / rel).read_bytes(), f'{package / rel} is not {source / rel}'
        direct = importlib.metadata.distribution(dist).read_text('direct_url.json')
        if direct:  # a pip install: editable, from this checkout
            info = json.loads(direct)
            assert info['dir_info'].get('editable') is True
            assert Path(info['url'].removeprefix('file://')).resolve() == REPO / 'src' / dist
