"""The transport baselines of `sagg bench graph`: the bare ping-pong and the contract's lockstep
exchange (command out, joint state and task point back), each between two real processes."""
import math

import pytest

from sagg_bringup.pingpong import measure


@pytest.mark.parametrize("pattern,raw", [("pingpong", False), ("lockstep", True), ("lockstep", False)])
def test_exchange_completes_between_two_processes(pattern, raw):
    res = measure(count=200, warmup=20, pattern=pattern, raw=raw, timeout=60.0)
    assert res["pattern"] == pattern and res["raw"] is raw
    assert res["complete"] and res["round_trips"] >= 200
    assert math.isfinite(res["rtt_ms"]) and res["rtt_ms"] > 0.0
    assert res["rate"] == pytest.approx(1000.0 / res["rtt_ms"])


def test_unknown_pattern_is_refused_by_name():
    with pytest.raises(ValueError, match=r"pattern: got 'ring'; allowed: pingpong, lockstep"):
        measure(pattern="ring")
