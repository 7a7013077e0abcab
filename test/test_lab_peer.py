"""lab.peer (the same-command comparison with explauto): what it checks before running the
peer, and its table. The peer itself needs its own venv (lab/peer.py's docstring), not CI's."""
from __future__ import annotations

import pytest

from sagg_lab.peer import arm_of, compare, table
from sagg_common.params import ConfigError


def test_the_peer_arm_must_be_expressible():
    spec, lp = arm_of("config/arm7_ratio15.yaml", {})
    assert (spec.dof, spec.link_ratio, spec.joint_limit) == (7, 1.5, spec.base_limit)
    with pytest.raises(ConfigError, match="one joint limit for every joint"):
        arm_of("config/arm7_ratio15.yaml", {"arm.base_limit": 1.5})
    # arm15 has no link ratio (equal links by profile): refused before anything runs
    with pytest.raises(ConfigError, match="link_ratio"):
        compare("config/arm15.yaml", "/nonexistent/python", 1, [10], [-2, -2, 2, 2], None, out=lambda s: None)


def test_table_gives_each_rate_against_the_peer_tree():
    r = lambda e, q: {"errors": {"5": e}, "queries_per_second": q}  # noqa: E731
    text = table({"config": {"peer tree": [r(0.2, 100.0), r(0.4, 300.0)],
                             "sagg-riac evolving": [r(0.1, 800.0), r(0.1, 800.0)]}}, [5])
    assert "| 5 queries | 0.3000 ± 0.1414 | 0.1000 ± 0.0000 |" in text
    assert "| queries/s | 200 | 800 |" in text and "| rate / peer tree's | 1.00 | 4.00 |" in text
