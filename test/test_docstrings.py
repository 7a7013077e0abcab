"""The algorithm cores document their public functions as scientific Python readers expect: a
numpydoc ``Parameters`` section (types and array shapes) when a function takes arguments, and
``Returns`` (or ``Yields``) when it gives something back."""
from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
CORES = ["sagg_common/sagg_common/regions.py", "sagg_common/sagg_common/competence.py",
         "sagg_low_level/sagg_low_level/local_model.py", "sagg_low_level/sagg_low_level/learner.py",
         "sagg_goal_generator/sagg_goal_generator/teacher.py", "sagg_goal_generator/sagg_goal_generator/alp_gmm.py",
         "sagg_goal_generator/sagg_goal_generator/discretized_progress.py",
         "sagg_goal_generator/sagg_goal_generator/core.py", "sagg_common/sagg_common/scene.py",
         "sagg_common/sagg_common/scene_model.py", "sagg_common/sagg_common/scene_params.py"]
PROPERTIES = {"property", "setter", "getter", "deleter", "cached_property"}


def _own_nodes(fn):
    """The nodes of ``fn``'s body, not those of functions, classes or lambdas inside it."""
    stack = list(fn.body)
    while stack:
        node = stack.pop()
        yield node
        stack += [c for c in ast.iter_child_nodes(node)
                  if not isinstance(c, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda))]


def _gives(fn) -> bool:
    ann = fn.returns
    if ann is not None and not (isinstance(ann, ast.Constant) and ann.value is None):
        return True
    return any(isinstance(n, (ast.Yield, ast.YieldFrom)) or (isinstance(n, ast.Return) and n.value is not None
               and not (isinstance(n.value, ast.Constant) and n.value.value is None)) for n in _own_nodes(fn))


def _has(doc: str, section: str) -> bool:
    lines = [s.strip() for s in doc.splitlines()]
    return any(a == section and b == "-" * len(section) for a, b in zip(lines, lines[1:]))


def missing_sections(path: Path) -> list[str]:
    out = []
    tree = ast.parse(path.read_text())
    funcs = [(f.name, f, False) for f in tree.body if isinstance(f, ast.FunctionDef)]
    for c in tree.body:
        if isinstance(c, ast.ClassDef) and not c.name.startswith("_"):
            funcs += [(f"{c.name}.{f.name}", f, True) for f in c.body if isinstance(f, ast.FunctionDef)]
    for name, f, method in funcs:
        decorators = {getattr(d, "id", getattr(d, "attr", "")) for d in f.decorator_list}
        if f.name.startswith("_") or decorators & PROPERTIES:
            continue
        doc = ast.get_docstring(f) or ""
        a = f.args
        args = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs][1 if method else 0:]
        if (args or a.vararg or a.kwarg) and not _has(doc, "Parameters"):
            out.append(f"{path.name}:{name}: no Parameters")
        if _gives(f) and not (_has(doc, "Returns") or _has(doc, "Yields")):
            out.append(f"{path.name}:{name}: no Returns")
    return out


def test_the_cores_public_functions_have_parameters_and_returns():
    assert [m for rel in CORES for m in missing_sections(SRC / rel)] == []


def test_the_check_sees_a_missing_section(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('def f(x):\n    """Doc.\n\n    Parameters\n    ----------\n    x : int\n        X.\n    """\n'
                 '    return x\n\nclass A:\n    def g(self):\n        """Doc."""\n\n    def _h(self, y):\n'
                 '        return y\n')
    assert missing_sections(f) == ["m.py:f: no Returns"]
