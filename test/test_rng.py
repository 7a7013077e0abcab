"""The named random streams' helpers (sagg_common.rng)."""
from __future__ import annotations

import numpy as np
import pytest

from sagg_common.rng import choice_index, stream


def test_choice_index_is_generator_choice_draw_for_draw():
    a, b, r = np.random.default_rng(5), np.random.default_rng(5), np.random.default_rng(1)
    for _ in range(5000):
        n = int(r.integers(1, 60))
        w = r.random(n) * (r.random(n) < 0.7)
        w = w if w.sum() > 0 else np.ones(n)
        p = w / w.sum()
        assert choice_index(b, p) == int(a.choice(n, p=p))
    assert a.random() == b.random()   # the streams stay in step


def test_streams_are_named_and_seeded():
    assert stream(3, "x").random() == stream(3, "x").random()
    assert stream(3, "x").random() != stream(3, "y").random()
    with pytest.raises(ValueError, match="seed"):
        stream(-1, "x")
