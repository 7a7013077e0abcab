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
import tempfile
from pathlib import Path


def repo_root() -> Path:
    """The git work tree of the current directory."""
    return Path(subprocess.run(["git", "rev-parse", "--show-toplevel"], capture_output=True, text=True,
                               check=True).stdout.strip())


@contextlib.contextmanager
def exported(commit: str, repo: Path | None = None):
    """Context manager: the ``src`` directory of ``commit`` (exported with ``git archive``)."""
    repo = repo or repo_root()
    with tempfile.TemporaryDirectory(prefix="sagg_base_") as tmp:
        archive = subprocess.run(["git", "-C", str(repo), "archive", commit, "src"], capture_output=True,
                                 check=True)
        subprocess.run(["tar", "-x", "-C", tmp], input=archive.stdout, check=True)
        yield Path(tmp) / "src"


def pythonpath(src: Path) -> str:
    """``PYTHONPATH`` putting every package directory of ``src`` first."""
    return os.pathsep.join(str(p) for p in sorted(src.iterdir()) if p.is_dir())


def check_source(imported: str, src: Path) -> None:
    """RuntimeError unless the module file ``imported`` lies under ``src``."""
    if not str(imported).startswith(str(src)):
        raise RuntimeError(f"the run imported {imported}, not the sources under {src}")
