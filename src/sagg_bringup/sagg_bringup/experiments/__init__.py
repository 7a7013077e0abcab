"""Experiments of many runs: ``sagg bench compare`` sweeps, their statistics, ``sagg reproduce``
(claims, sensitivity, archive, mechanisms)."""
