"""History stays out of the code, the tests and the user pages: comments and docstrings say what the
code does (a test: what it checks) and why, not when it changed (dates, issue numbers) or what a
design file outside the repository said; the user pages (README.md and docs/*.md; not the lab
notebook docs/notes/ nor the reproduction archive) carry no commit hash, issue number, machine load
or /tmp path. Dates, issues, commits and measurements belong in commit messages and docs/notes/."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SRC_SUFFIXES = {".py", ".c", ".h", ".yaml", ".xml", ".cfg", ".txt"}
DATE = re.compile(r"\b20\d\d-\d\d-\d\d\b")
ISSUE = re.compile(r"\bissues? \d+|\bissue \d+'s", re.IGNORECASE)
DESIGN = re.compile(r"\bDESIGN\b")
# a commit hash: 7-40 hex digits with at least one letter and one digit
COMMIT = re.compile(r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b")
LOAD = re.compile(r"load average|\bat load \d|\(load \d|engineers' jobs", re.IGNORECASE)
TMP = re.compile(r"/tmp/")


def hits(paths, *patterns) -> list[str]:
    out = []
    for path in paths:
        for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if any(p.search(line) for p in patterns):
                name = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
                out.append(f"{name}:{n}: {line.strip()[:140]}")
    return out


def source_files() -> list[Path]:
    return sorted(p for p in (ROOT / "src").rglob("*") if p.is_file() and p.suffix in SRC_SUFFIXES
                  and "__pycache__" not in p.parts and ".egg-info" not in str(p))


def files_of_test() -> list[Path]:
    """Every Python file of test/ but this one (whose patterns and examples must name what they find)."""
    return sorted(p for p in (ROOT / "test").rglob("*.py") if "__pycache__" not in p.parts
                  and p.name != Path(__file__).name)


def user_pages() -> list[Path]:
    return [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))


def test_the_code_tells_no_history():
    assert hits(source_files(), DATE, ISSUE, DESIGN) == []


def test_the_tests_tell_no_history():
    assert hits(files_of_test(), DATE, ISSUE, DESIGN) == []


def test_the_user_pages_tell_no_history():
    assert hits(user_pages(), COMMIT, ISSUE, LOAD, TMP) == []
    # the reproduction archive's index keeps each number's commit, but no scratch path
    assert hits([ROOT / "docs/reproduction/README.md"], TMP) == []


def test_the_patterns_see_what_they_must(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("fine: 2 cores, v 0.5, 1,234 goals, cafe\n"
                    "measured at d514e4c\nsee issue 10\nrun under load average 13\n"
                    "sagg run --out /tmp/x\nbefore 2026-11-23 it did\nas DESIGN §8 says\n")
    found = [h.split(": ", 1)[1] for h in hits([page], COMMIT, ISSUE, LOAD, TMP, DATE, DESIGN)]
    assert found == ["measured at d514e4c", "see issue 10", "run under load average 13", "sagg run --out /tmp/x",
                     "before 2026-11-23 it did", "as DESIGN §8 says"]
