"""Shared by every test: the tests run from the repository root.

`make test` starts pytest there; `colcon test` starts it in src/sagg_bringup (that package's
setup.cfg points pytest at this folder). Tests name the repository's configs and robot models as
`config/...`, as the README and the docs do (colcon installs the same files into
share/sagg_bringup), so the working directory is the repository root for every test, whoever
started pytest. (At session start, not at import: pytest resolves its testpaths after loading
this file.)"""
import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def pytest_sessionstart(session):
    os.chdir(ROOT)
