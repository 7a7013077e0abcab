"""`sagg bench` and its plug-ins: the lab's benchmarks come from the separately installed
sagg_lab as entry points; without them `sagg bench` still offers compare and table and says how to
get the rest."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from sagg_bringup.cli import cli
from sagg_bringup.cli.benches import GROUP, Bench, installed_benches

ROOT = Path(__file__).resolve().parents[1]


def declared_benches() -> dict[str, str]:
    """name -> object of the entry points src/sagg_lab/setup.py declares in the sagg.bench group."""
    text = (ROOT / "src" / "sagg_lab" / "setup.py").read_text()
    assert f"'{GROUP}'" in text
    return dict(re.findall(r"'(\w+) = sagg_lab\.benches:(\w+)'", text))


def test_the_installed_lab_benches_are_those_sagg_lab_declares():
    declared = declared_benches()
    assert set(declared) == {"speed", "graph", "riac", "soak", "hostile", "quality"}
    benches = installed_benches()
    assert set(benches) == set(declared)
    import sagg_lab.benches as lab
    for name, obj in declared.items():
        assert benches[name] is getattr(lab, obj)
        assert isinstance(benches[name], Bench) and benches[name].help


def test_a_plugin_brings_its_own_options(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["bench", "riac", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "--micro-actions" in out and "--window" in out


def test_without_the_lab_bench_keeps_compare_and_table_and_says_how_to_get_the_rest(monkeypatch, capsys):
    monkeypatch.setattr(cli, "installed_benches", lambda: {})
    with pytest.raises(SystemExit) as exc:
        cli.main(["bench", "speed"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'speed'" in err and "make lab" in err
    with pytest.raises(SystemExit) as exc:
        cli.main(["bench", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "{compare,table}" in out and "make lab" in out
