"""The goal generator's compiled kernel (em_kernel.c: the alp-gmm teacher's EM and nearest-goal search), built with the
package by its setup.py, imported in one place so that a source checkout without its build step says
what to do."""
from __future__ import annotations

try:
    from . import em_kernel
except ImportError as exc:  # a source checkout used without its build step
    raise ImportError("sagg_goal_generator.em_kernel (em_kernel.c) is not built: run `make setup`, "
                      "`pip install -e src/sagg_goal_generator` or `colcon build`") from exc

__all__ = ["em_kernel"]
