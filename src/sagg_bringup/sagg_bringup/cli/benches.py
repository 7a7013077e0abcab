"""The ``sagg bench`` plug-ins: benchmarks that other packages add to the command.

``sagg bench compare`` and ``sagg bench table`` belong to the product (sagg_bringup.experiments).
The measuring tools (speed, graph, riac, soak, hostile, quality) live in the separate package
``sagg_lab``, which the runtime never imports: it registers each of them as an entry point of the
group :data:`GROUP` (as ros2cli's command extensions do), and ``sagg`` lists whatever is installed.
``make test`` and ``make lab`` install sagg_lab; ``make run`` does not.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Callable

GROUP = "sagg.bench"
LAB_HINT = ("more benchmarks (speed, graph, riac, soak, hostile, quality) come with the lab tools: "
            "`make lab` (make test installs them too) or `pip install -e src/sagg_lab`")


@dataclass(frozen=True)
class Bench:
    """One ``sagg bench NAME`` subcommand: its help line, its options, and what it runs (returns the
    exit code)."""
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def installed_benches() -> dict[str, Bench]:
    """Name -> :class:`Bench` of every installed plug-in (entry points of :data:`GROUP`), by name."""
    out = {}
    for ep in sorted(entry_points(group=GROUP), key=lambda e: e.name):
        bench = ep.load()
        if not isinstance(bench, Bench):
            raise TypeError(f"entry point {ep.name} = {ep.value} of group {GROUP}: not a sagg Bench")
        out[ep.name] = bench
    return out


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {v}")
    return v
