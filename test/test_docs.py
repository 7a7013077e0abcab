"""The README documents every parameter, exactly as the schemas say."""
from pathlib import Path

from sagg_bringup.cli import PARAMS_BEGIN, PARAMS_END, node_schemas, params_markdown

README = Path(__file__).resolve().parents[1] / "README.md"


def test_readme_parameter_tables_are_current():
    text = README.read_text()
    block = text.split(PARAMS_BEGIN, 1)[1].split(PARAMS_END, 1)[0].strip()
    assert block == params_markdown().strip(), (
        "README parameter tables are stale: run `.venv/bin/sagg params --update-readme README.md`")


def test_every_parameter_has_a_description_and_appears_in_readme():
    text = README.read_text()
    for node, schema in node_schemas().items():
        for p in schema:
            assert len(p.description) > 10, f"{node}.{p.name} lacks a description"
            assert f"| `{p.name}` |" in text
