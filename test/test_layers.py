"""The package layers (issue 13): imports point down, no import cycles, no private rclpy API.

Layers: sagg_msgs <- sagg_common <- {sagg_goal_generator, sagg_low_level, sagg_sim_bridge} <-
sagg_bringup; the three middle packages do not import each other. Every ``import`` statement
counts, at module level or inside a function: an import hidden in a function still makes the
dependency (lazy imports are only for start-up cost, never to dodge a cycle).

``python test/test_layers.py`` prints the import graph of src/ (module -> modules it imports).
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
LAYERS = {"sagg_msgs": 0, "sagg_common": 1, "sagg_goal_generator": 2, "sagg_low_level": 2,
          "sagg_sim_bridge": 2, "sagg_bringup": 3}


def source_modules(src: Path = SRC) -> dict[str, Path]:
    """Dotted module name -> file, for every Python module of the layered packages."""
    out = {}
    for pkg in LAYERS:
        root = src / pkg / pkg
        for f in sorted(root.rglob("*.py")) if root.is_dir() else ():
            parts = list(f.relative_to(src / pkg).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = f
    return out


def _imported_modules(node: ast.AST, module: str, is_package: bool, mods: dict) -> set[str]:
    """The project modules an import statement imports (``from m import x``: m.x if that is a
    module, else m; sagg_msgs counts as one module: its Python code is generated)."""
    def resolve(name: str) -> str | None:
        if name.split(".")[0] == "sagg_msgs":
            return "sagg_msgs"
        while name not in mods and "." in name:
            name = name.rsplit(".", 1)[0]
        return name if name in mods else None

    if isinstance(node, ast.Import):
        found = {resolve(a.name) for a in node.names}
    else:
        if node.level:
            base = module.split(".") if is_package else module.split(".")[:-1]
            base = base[: len(base) - node.level + 1]
            mod = ".".join(base + ([node.module] if node.module else []))
        else:
            mod = node.module or ""
        found = {f"{mod}.{a.name}" if f"{mod}.{a.name}" in mods else resolve(mod) for a in node.names}
    return {m for m in found if m is not None and m != module}


def import_graph(src: Path = SRC) -> dict[str, set[str]]:
    """Module -> the project modules it imports (anywhere in the file)."""
    mods = source_modules(src)
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                deps |= _imported_modules(node, name, path.name == "__init__.py", mods)
        graph[name] = deps
    return graph


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    """Imports that point up, or sideways between the three middle packages."""
    bad = []
    for mod, deps in graph.items():
        pkg = mod.split(".")[0]
        for dep in deps:
            dpkg = dep.split(".")[0]
            if dpkg != pkg and LAYERS[dpkg] >= LAYERS[pkg]:
                bad.append(f"{mod} -> {dep}")
    return sorted(bad)


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(out)


# ------------------------------------------------------------------------------ the checks
def test_imports_point_down():
    assert layer_violations(import_graph()) == []


def test_no_import_cycles():
    assert cycles(import_graph()) == []


def test_lab_tools_only_behind_the_command_line():
    """Lab tools (sagg_bringup.lab: benchmarks, soaks, figure scripts) are imported by each other and
    by the ``sagg bench`` commands of the CLI, never by the product modules."""
    g = import_graph()
    users = {mod for mod, deps in g.items() for dep in deps
             if dep.startswith("sagg_bringup.lab") and not mod.startswith("sagg_bringup.lab")}
    assert users == {"sagg_bringup.cli"}


def test_the_checks_see_what_they_must(tmp_path):
    """The graph builder on a small fake tree: an upward import, a sideways one and a cycle hidden
    in a function are all found; relative imports resolve."""
    files = {
        "sagg_common/sagg_common/__init__.py": "",
        "sagg_common/sagg_common/a.py": "def f():\n    from sagg_low_level.b import g\n",
        "sagg_low_level/sagg_low_level/__init__.py": "",
        "sagg_low_level/sagg_low_level/b.py": "from . import c\nfrom sagg_sim_bridge import d\n",
        "sagg_low_level/sagg_low_level/c.py": "def h():\n    from .b import x\n",
        "sagg_sim_bridge/sagg_sim_bridge/__init__.py": "",
        "sagg_sim_bridge/sagg_sim_bridge/d.py": "import sagg_common.a\nfrom sagg_msgs.msg import Goal\n",
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    g = import_graph(tmp_path)
    assert g["sagg_low_level.b"] == {"sagg_low_level.c", "sagg_sim_bridge.d"}
    assert g["sagg_sim_bridge.d"] == {"sagg_common.a", "sagg_msgs"}
    assert layer_violations(g) == ["sagg_common.a -> sagg_low_level.b", "sagg_low_level.b -> sagg_sim_bridge.d"]
    assert cycles(g) == [["sagg_common.a", "sagg_low_level.b", "sagg_low_level.c", "sagg_sim_bridge.d"]]


# ----------------------------------------------------------------------- private rclpy API
def rclpy_private_names() -> set[str]:
    """Names of rclpy's private attributes and methods (``_x``, not dunder): every ``self._x``
    assigned and every ``def _x`` in rclpy's Python sources."""
    import rclpy

    names: set[str] = set()
    for f in Path(rclpy.__file__).parent.rglob("*.py"):
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                names.add(node.name)
            elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
                names.add(node.attr)
    return {n for n in names if n.startswith("_") and not n.startswith("__")}


def private_uses(tree: ast.AST, private: set[str]) -> list[str]:
    """Uses of ``private`` names on objects other than ``self``/``cls`` (attribute access or a
    ``getattr``/``setattr``/``hasattr`` string), and any assignment to ``__class__``."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            owner = node.value.id if isinstance(node.value, ast.Name) else None
            if node.attr == "__class__" and isinstance(node.ctx, ast.Store):
                found.append(f"line {node.lineno}: assignment to __class__")
            elif node.attr in private and owner not in ("self", "cls"):
                found.append(f"line {node.lineno}: .{node.attr}")
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
              and node.func.id in ("getattr", "setattr", "hasattr") and len(node.args) >= 2
              and isinstance(node.args[1], ast.Constant) and node.args[1].value in private):
            found.append(f"line {node.lineno}: {node.func.id}(..., {node.args[1].value!r})")
    return found


def test_no_private_rclpy_api_in_src():
    """No module of src/ reaches into rclpy's private attributes (e.g. ``node._parameter_overrides``)
    or swaps an rclpy object's class: both break silently on an rclpy update. Our own classes'
    private names count only where they coincide with an rclpy one and are used on another object."""
    private = rclpy_private_names()
    assert {"_parameter_overrides", "_parameters"} <= private  # the scan sees rclpy's internals
    bad = {}
    for name, path in source_modules().items():
        found = private_uses(ast.parse(path.read_text(), str(path)), private)
        if found:
            bad[name] = found
    assert bad == {}


def test_private_use_checker_finds_the_old_patterns():
    old = ("overrides = getattr(node, '_parameter_overrides', {})\n"
           "srv.__class__ = DeferrableService\n"
           "x = node._parameters\n"
           "self._parameters = {}\n")
    found = private_uses(ast.parse(old), rclpy_private_names())
    assert found == ["line 1: getattr(..., '_parameter_overrides')", "line 2: assignment to __class__",
                     "line 3: ._parameters"]


if __name__ == "__main__":
    g = import_graph()
    for mod in sorted(g):
        print(f"{mod} -> {', '.join(sorted(g[mod])) or '-'}")
    problems = layer_violations(g)
    print(f"\n{len(g)} modules, {sum(map(len, g.values()))} imports; upward/sideways: {problems or 'none'}; "
          f"cycles: {cycles(g) or 'none'}")
    sys.exit(1 if problems or cycles(g) else 0)
