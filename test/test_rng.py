"""The named random streams' helpers (sagg_common.rng)."""
from __future__ import annotations

import numpy as np
import pytest

from sagg_common.rng import choice_index, stream, uniform_in


def test_choice_index_is_generator_choice_draw_for_draw():
    a, b, r = np.random.default_rng(5), np.random.default_rng(5), np.random.default_rng(1)
    for _ in range(5000):
        n = int(r.integers(1, 60))
        w = r.random(n) * (r.random(n) < 0.7)
        w = w if w.sum() > 0 else np.ones(n)
        p = w / w.sum()
        assert choice_index(b, p) == int(a.choice(n, p=p))
    assert a.random() == b.random()   # the streams stay in step


def test_uniform_in_is_generator_uniform_draw_for_draw():
    a, b, r = np.random.default_rng(7), np.random.default_rng(7), np.random.default_rng(2)
    for _ in range(3000):
        n = int(r.integers(1, 31))
        # bounds of many magnitudes and signs, some empty (lower == upper)
        lower = r.normal(0.0, 1.0, n) * 10.0 ** r.integers(-6, 7, n)
        upper = lower + np.abs(r.normal(0.0, 1.0, n)) * 10.0 ** r.integers(-6, 7, n) * (r.random(n) < 0.9)
        assert uniform_in(b, lower, upper).tobytes() == a.uniform(lower, upper).tobytes()
    assert a.random() == b.random()   # the streams stay in step


def test_streams_are_named_and_seeded():
    assert stream(3, "x").random() == stream(3, "x").random()
    assert stream(3, "x").random() != stream(3, "y").random()
    with pytest.raises(ValueError, match="seed"):
        stream(-1, "x")
