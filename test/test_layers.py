"""The package layers: imports point down, no import cycles, no private rclpy API.

Layers: sagg_msgs <- sagg_common <- {sagg_goal_generator, sagg_low_level, sagg_sim_bridge} <-
sagg_bringup <- sagg_lab; the three middle packages do not import each other, and nothing imports
sagg_lab (the measuring tools: ``sagg bench`` finds its benchmarks as entry points). Inside
sagg_bringup, the job packages are layered too (:data:`BRINGUP_JOBS`, bottom to top: report <-
inprocess <- bags <- graph <- experiments <- cli): each imports only the ones below it. Every ``import`` statement
counts, at module level or inside a function: an import hidden in a function still makes the
dependency (lazy imports are only for start-up cost, never to dodge a cycle). An import inside a
function must be of a heavy module (:data:`HEAVY_ROOTS`, ROS interface packages, or a project module
that imports one at module level) and say so with a ``# lazy (heavy)`` comment on the line above
its block of imports; everything else is imported at the top of the module.

``python test/test_layers.py`` prints the import graph of src/ (module -> modules it imports).
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
LAYERS = {"sagg_msgs": 0, "sagg_common": 1, "sagg_goal_generator": 2, "sagg_low_level": 2,
          "sagg_sim_bridge": 2, "sagg_bringup": 3, "sagg_lab": 4}
# The sub-packages of sagg_bringup by job, bottom to top (docs/architecture.md): each imports only
# the ones before it. report: run reports; inprocess: one run without ROS and what every run shares;
# bags: writing, reading, replaying and relearning bags; graph: the ROS 2 graph of a run and the
# set-up registry; experiments: comparisons of many runs, reproduction; cli: the `sagg` command.
BRINGUP_JOBS = ("report", "inprocess", "bags", "graph", "experiments", "cli")


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


def bringup_job_violations(graph: dict[str, set[str]]) -> list[str]:
    """Imports between sagg_bringup's job packages that do not point down :data:`BRINGUP_JOBS`
    """
    bad = []
    for mod, deps in graph.items():
        parts = mod.split(".")
        if parts[0] != "sagg_bringup" or len(parts) < 2:
            continue
        for dep in deps:
            dparts = dep.split(".")
            if dparts[0] != "sagg_bringup" or len(dparts) < 2 or dparts[1] == parts[1]:
                continue
            if (parts[1] not in BRINGUP_JOBS or dparts[1] not in BRINGUP_JOBS
                    or BRINGUP_JOBS.index(dparts[1]) >= BRINGUP_JOBS.index(parts[1])):
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


# ------------------------------------------------------------------ imports inside functions
# Third-party packages worth loading only on the paths that use them (import times measured here at
# load ~3: rclpy 0.45 s, mujoco 0.64 s, matplotlib 0.49 s, scipy 0.17-0.47 s, rosbags.highlevel
# 0.09 s), and ROS interface packages (their type support is loaded with rclpy).
HEAVY_ROOTS = frozenset({"rclpy", "mujoco", "matplotlib", "scipy", "rosbags", "ray", "sklearn"})
LAZY_MARK = "# lazy (heavy)"


def _heavy_root(name: str) -> bool:
    root = name.split(".")[0]
    return root in HEAVY_ROOTS or root.endswith(("_msgs", "_srvs", "_interfaces"))


def _top_level_imports(tree: ast.Module) -> list:
    """The import statements run when the module is imported (module body, incl. if/try blocks)."""
    out = []

    def walk(nodes):
        for n in nodes:
            if isinstance(n, (ast.Import, ast.ImportFrom)):
                out.append(n)
            elif isinstance(n, (ast.If, ast.Try)):
                walk(n.body)
                walk(n.orelse)
                walk(getattr(n, "finalbody", []))
                for h in getattr(n, "handlers", []):
                    walk(h.body)
    walk(tree.body)
    return out


def _external_names(node) -> list[str]:
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    return [node.module] if node.module and not node.level else []


def heavy_roots(src: Path = SRC) -> dict[str, frozenset[str]]:
    """Project module -> the heavy packages its import loads (directly or through project modules,
    module-level imports only); ROS interface packages count as one root, "ROS", with rclpy."""
    mods = source_modules(src)
    direct, deps = {}, {}
    for name, path in mods.items():
        tl = _top_level_imports(ast.parse(path.read_text(), str(path)))
        direct[name] = {_root(x) for n in tl for x in _external_names(n) if _heavy_root(x)}
        deps[name] = set().union(set(), *(_imported_modules(n, name, path.name == "__init__.py", mods) for n in tl))
    roots = {name: set(r) for name, r in direct.items()}
    roots["sagg_msgs"] = {"ROS"}
    changed = True
    while changed:
        changed = False
        for name in mods:
            new = set().union(roots[name], *(roots.get(d, set()) for d in deps[name]))
            if new != roots[name]:
                roots[name] = new
                changed = True
    return {name: frozenset(r) for name, r in roots.items()}


def _root(name: str) -> str:
    root = name.split(".")[0]
    return "ROS" if root == "rclpy" or root.endswith(("_msgs", "_srvs", "_interfaces")) else root


def function_imports(src: Path = SRC) -> list[tuple[str, int, str, bool, bool]]:
    """Every import statement inside a function: (file, line, statement, marked with
    :data:`LAZY_MARK` on the line above its block, heavy: each module it imports loads a heavy
    package that the importing module does not already load at module level)."""
    mods = source_modules(src)
    roots = heavy_roots(src)
    project = {m.split(".")[0] for m in mods}
    out = []
    for name, path in mods.items():
        text = path.read_text()
        lines = text.splitlines()
        own = roots[name]
        for f in ast.walk(ast.parse(text, str(path))):
            if not isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for body in (getattr(n, field) for n in ast.walk(f) for field in ("body", "orelse", "finalbody")
                         if isinstance(getattr(n, field, None), list)):
                block_start = None
                for st in body:
                    if not isinstance(st, (ast.Import, ast.ImportFrom)):
                        block_start = None
                        continue
                    if block_start is None:
                        block_start = st.lineno
                    marked = block_start >= 2 and lines[block_start - 2].strip().startswith(LAZY_MARK)
                    proj = _imported_modules(st, name, path.name == "__init__.py", mods)
                    ext = [x for x in _external_names(st) if x.split(".")[0] not in project]
                    is_heavy = (all(roots[m] - own for m in proj)
                                and all(_heavy_root(x) and _root(x) not in own for x in ext))
                    out.append((str(path.relative_to(src)), st.lineno, ast.unparse(st), marked, is_heavy))
    return sorted(set(out))


# ------------------------------------------------------------------------------ the checks
def test_imports_point_down():
    assert layer_violations(import_graph()) == []


def test_no_import_cycles():
    assert cycles(import_graph()) == []


def test_nothing_imports_the_lab():
    """The measuring tools (sagg_lab) sit above the product: no module of another package imports
    them, not even inside a function (``sagg bench`` loads them as entry points)."""
    g = import_graph()
    assert "sagg_lab.benches" in g
    users = {mod for mod, deps in g.items() for dep in deps
             if dep.startswith("sagg_lab") and not mod.startswith("sagg_lab")}
    assert users == set()


def test_bringup_job_packages_import_down():
    assert bringup_job_violations(import_graph()) == []


def test_every_bringup_module_sits_in_a_job_package():
    """sagg_bringup holds no flat module: each module is in one job package."""
    root = SRC / "sagg_bringup" / "sagg_bringup"
    flat = sorted(f.name for f in root.glob("*.py") if f.name != "__init__.py")
    packages = sorted(d.name for d in root.iterdir() if (d / "__init__.py").is_file())
    assert flat == []
    assert packages == sorted(BRINGUP_JOBS)


def test_the_job_check_sees_what_it_must():
    g = {"sagg_bringup.report.report": {"sagg_bringup.graph.session", "sagg_common.params"},
         "sagg_bringup.graph.session": {"sagg_bringup.report.report", "sagg_bringup.graph.processes"},
         "sagg_bringup.experiments.sweep": {"sagg_bringup.cli.cli"},
         "sagg_bringup.cli.cli": {"sagg_bringup.experiments.sweep", "sagg_bringup.cli.benches"},
         "sagg_bringup.graph.setups": {"sagg_bringup.inprocess.experiment"}}
    assert bringup_job_violations(g) == ["sagg_bringup.experiments.sweep -> sagg_bringup.cli.cli",
                                         "sagg_bringup.report.report -> sagg_bringup.graph.session"]
    g2 = {"sagg_bringup.graph.setups": {"sagg_lab.bench"}, "sagg_lab.bench": {"sagg_bringup.graph.setups"}}
    assert layer_violations(g2) == ["sagg_bringup.graph.setups -> sagg_lab.bench"]


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


def test_imports_inside_functions_are_heavy_and_say_so():
    """No import hides in a function unless it loads a heavy package and carries the lazy comment
    (a light one, or one that dodges a cycle, belongs at the top of the module)."""
    bad = [f"{f}:{line}: {st}" + ("" if heavy else "  (light: import it at the top)")
           + ("" if marked else f"  (no '{LAZY_MARK}' comment above its block)")
           for f, line, st, marked, heavy in function_imports() if not (marked and heavy)]
    assert bad == []


def test_no_imports_inside_functions_of_launch_and_setup_files():
    """The Python files of src/ outside the packages (launch files, setup.py) import at the top."""
    packages = set(source_modules().values())
    bad = []
    for path in sorted(set(SRC.rglob("*.py")) - packages):
        for f in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)):
                bad += [f"{path.relative_to(SRC)}:{n.lineno}" for n in ast.walk(f)
                        if isinstance(n, (ast.Import, ast.ImportFrom))]
    assert bad == []


def test_the_lazy_import_check_sees_what_it_must(tmp_path):
    files = {
        "sagg_common/sagg_common/__init__.py": "",
        "sagg_common/sagg_common/light.py": "import json\n",
        "sagg_common/sagg_common/heavyish.py": "from . import light\nimport rclpy.node\n",
        "sagg_common/sagg_common/user.py": (
            "def a():\n    # lazy (heavy): rclpy\n    import rclpy\n    from . import heavyish\n"
            "def b():\n    from . import light\n"
            "def c():\n    import mujoco\n"
            "def d():\n    # lazy (heavy)\n    import json\n"
            "def e():\n    x = 1\n    if x:\n        # lazy (heavy)\n        from sagg_msgs.msg import Goal\n"),
        # already loads ROS at module level: a lazy ROS import buys nothing
        "sagg_common/sagg_common/rosuser.py": (
            "import rclpy\ndef f():\n    # lazy (heavy)\n    from . import heavyish\n"),
    }
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    roots = heavy_roots(tmp_path)
    assert {m for m, r in roots.items() if r} == {"sagg_msgs", "sagg_common.heavyish", "sagg_common.rosuser"}
    assert roots["sagg_common.heavyish"] == {"ROS"}
    found = {(line, marked, heavy) for f, line, st, marked, heavy in function_imports(tmp_path)
             if f.endswith("/user.py")}
    assert found == {(3, True, True), (4, True, True), (6, False, False), (8, False, True), (11, True, False),
                     (16, True, True)}
    assert [(line, heavy) for f, line, st, marked, heavy in function_imports(tmp_path)
            if f.endswith("/rosuser.py")] == [(4, False)]


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
    ``getattr``/``setattr``/``hasattr`` string), any assignment to ``__class__``, and imports of
    rclpy's private modules (``rclpy._rclpy_pybind11``, ``rclpy.impl``)."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            for name in names:
                parts = name.split(".")
                if parts[0] == "rclpy" and any(p.startswith("_") or p == "impl" for p in parts[1:]):
                    found.append(f"line {node.lineno}: import of {name}")
                    break
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
    return sorted(found, key=lambda f: int(f.split()[1].rstrip(":")))


def checked_python_files() -> list[Path]:
    """Every Python file of the project: all of src/ (the packages, launch files, setup.py) and the
    test helpers and tests."""
    root = SRC.parent
    return sorted(set(SRC.rglob("*.py")) | set((root / "test").rglob("*.py")))


def test_no_private_rclpy_api_anywhere():
    """No Python file of src/ or test/ reaches into rclpy's private attributes (e.g.
    ``node._parameter_overrides``), imports its private modules or swaps an rclpy object's class:
    all break silently on an rclpy update. Our own classes' private names count only where they
    coincide with an rclpy one and are used on another object."""
    private = rclpy_private_names()
    assert {"_parameter_overrides", "_parameters"} <= private  # the scan sees rclpy's internals
    files = checked_python_files()
    assert set(source_modules().values()) < set(files)  # every package module, and more
    assert any(f.name.endswith(".launch.py") for f in files) and any(f.name == "fake_driver.py" for f in files)
    bad = {}
    for path in files:
        found = private_uses(ast.parse(path.read_text(), str(path)), private)
        if found:
            bad[str(path.relative_to(SRC.parent))] = found
    assert bad == {}


def test_private_use_checker_finds_the_old_patterns():
    old = ("overrides = getattr(node, '_parameter_overrides', {})\n"
           "srv.__class__ = DeferrableService\n"
           "x = node._parameters\n"
           "self._parameters = {}\n"
           "from rclpy.impl.implementation_singleton import rclpy_implementation\n"
           "import rclpy._rclpy_pybind11\n"
           "from rclpy import _rclpy_pybind11\n"
           "from rclpy.node import Node\n")
    found = private_uses(ast.parse(old), rclpy_private_names())
    assert found == ["line 1: getattr(..., '_parameter_overrides')", "line 2: assignment to __class__",
                     "line 3: ._parameters", "line 5: import of rclpy.impl.implementation_singleton",
                     "line 6: import of rclpy._rclpy_pybind11", "line 7: import of rclpy._rclpy_pybind11"]


if __name__ == "__main__":
    g = import_graph()
    for mod in sorted(g):
        print(f"{mod} -> {', '.join(sorted(g[mod])) or '-'}")
    problems = layer_violations(g) + bringup_job_violations(g)
    print(f"\n{len(g)} modules, {sum(map(len, g.values()))} imports; upward/sideways: {problems or 'none'}; "
          f"cycles: {cycles(g) or 'none'}")
    sys.exit(1 if problems or cycles(g) else 0)
