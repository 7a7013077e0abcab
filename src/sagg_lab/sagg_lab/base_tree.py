"""An older commit's sources beside this tree's, for before/after measurements in one command.

:func:`exported` writes ``git archive <commit> src`` into a temporary directory;
:func:`pythonpath` is the ``PYTHONPATH`` that makes a child process import a ``src/`` tree's
packages before the installed (editable) ones; :func:`check_source` verifies a child imported
what it was meant to.
"""
from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import tempfile
from pathlib import Path


def repo_root() -> Path:
    """The git work tree of the current directory."""
    return Path(subprocess.run(["git", "rev-parse", "--show-toplevel"], capture_output=True, text=True,
                               check=True).stdout.strip())


@contextlib.contextmanager
def exported(commit: str, repo: Path | None = None):
    """Context manager: the ``src`` directory of ``commit`` (exported with ``git archive``), its
    compiled extensions built in place (each package's own setup.py, as every install does), so
    that the commit's own compiled code runs: not this tree's, which an editable install's finder
    would otherwise supply, and which a colcon workspace does not offer at all."""
    repo = repo or repo_root()
    with tempfile.TemporaryDirectory(prefix="sagg_base_") as tmp:
        archive = subprocess.run(["git", "-C", str(repo), "archive", commit, "src"], capture_output=True,
                                 check=True)
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        src = Path(tmp) / "src"
        for setup in sorted(src.glob("*/setup.py")):
            if any(setup.parent.glob("*/*.c")):
                subprocess.run([sys.executable, "setup.py", "-q", "build_ext", "--inplace"], cwd=setup.parent,
                               capture_output=True, check=True)
        yield src


def pythonpath(src: Path) -> str:
    """``PYTHONPATH`` putting every package directory of ``src`` first, then the environment's (a
    sourced colcon workspace has its interface packages there)."""
    dirs = [str(p) for p in sorted(src.iterdir()) if p.is_dir()]
    return os.pathsep.join(dirs + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])


def check_source(imported: str, src: Path) -> None:
    """RuntimeError unless the module file ``imported`` lies under ``src``."""
    if not str(imported).startswith(str(src)):
        raise RuntimeError(f"the run imported {imported}, not the sources under {src}")
