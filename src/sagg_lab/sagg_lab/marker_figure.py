"""The README's live-view screenshot: the last ``/sagg/markers`` MarkerArray of a bag, drawn from
above with matplotlib (:func:`sagg_bringup.graph.markers.render_markers`).

    .venv/bin/python -m sagg_lab.marker_figure RUN/bag docs/figures/markers.png [--title T]
"""
from __future__ import annotations

import argparse
import sys

from sagg_bringup.graph.markers import marker_arrays_from_bag, render_markers


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bag")
    ap.add_argument("png")
    ap.add_argument("--title", default="")
    a = ap.parse_args(argv)
    arrays = marker_arrays_from_bag(a.bag)
    if not arrays:
        print(f"no /sagg/markers message in {a.bag}", file=sys.stderr)
        return 1
    print(f"{len(arrays)} MarkerArray messages; drawing the last ({len(arrays[-1].markers)} markers) -> "
          f"{render_markers(arrays[-1], a.png, a.title)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
