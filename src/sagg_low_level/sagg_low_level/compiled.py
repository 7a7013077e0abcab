"""The compiled inner loops of the neighbour searches (knn_kernel.c, built with the package by its
setup.py), imported in one place so that a source checkout without its build step says what to do."""
from __future__ import annotations

try:
    from . import knn_kernel
except ImportError as exc:  # a source checkout used without its build step
    raise ImportError("sagg_low_level.knn_kernel (knn_kernel.c) is not built: run `make setup`, "
                      "`pip install -e src/sagg_low_level` or `colcon build`") from exc

__all__ = ["knn_kernel"]
