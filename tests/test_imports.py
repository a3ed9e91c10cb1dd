"""The project's import graph: no circle among its modules, the library below the agents, the
env below the analysis layer.

Every ``import`` and ``from ... import`` statement counts, at module level or inside a function
(a function-level import is a dependency all the same, only a late one). An import names the
deepest project module it reaches: ``from .margins import PlantModel`` is an edge to
``bogie_agents.design.margins``, ``from . import task`` one to ``bogie_env.envs.task``. A package's
``__init__`` is not implied by importing a module inside it (that edge runs the other way by
construction). Modules named by string (``importlib.import_module``, the protocol's part
registry) are not imports here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
#: package name -> its source folder (the repository folder agents/ installs as bogie_agents)
PACKAGES = {"bogie_env": ROOT / "bogie_env", "bogie_agents": ROOT / "agents"}


def project_modules(packages: dict[str, Path]) -> dict[str, Path]:
    """Dotted module name -> source file, for every ``.py`` file below each package folder."""
    modules = {}
    for package, folder in packages.items():
        for path in sorted(folder.rglob("*.py")):
            parts = [package, *path.relative_to(folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = path
    return modules


def _absolute(module: str, is_package: bool, level: int, name: str | None) -> str:
    """The absolute name of ``from <level dots><name> import ...`` written in ``module``."""
    if not level:
        return name or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def _project_module(name: str, modules: dict[str, Path]) -> str | None:
    """The deepest project module that ``name`` (a module or a name inside one) is, or is in."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def import_graph(packages: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports (module and function level)."""
    modules = project_modules(packages)
    graph: dict[str, set[str]] = {}
    for module, path in modules.items():
        is_package = path.name == "__init__.py"
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _absolute(module, is_package, node.level, node.module)
                names = [f"{base}.{alias.name}" for alias in node.names]  # a submodule, else a name in base
            else:
                continue
            for name in names:
                target = _project_module(name, modules)
                if target is not None and target != module:
                    targets.add(target)
        graph[module] = targets
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One closed path ``[a, b, ..., a]`` per strongly connected group of modules that import
    each other (empty: the graph has no circle)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[set[str]] = []

    def visit(v: str) -> None:  # Tarjan's algorithm (the graph is small: recursion is fine)
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.add(w)
                if w == v:
                    break
            if len(group) > 1 or v in graph.get(v, ()):
                groups.append(group)

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return [_closed_path(graph, group) for group in groups]


def _closed_path(graph: dict[str, set[str]], group: set[str]) -> list[str]:
    """A shortest circle through the group's first module (breadth-first, inside the group)."""
    start = min(group)
    previous: dict[str, str] = {}
    queue = [start]
    while queue:
        v = queue.pop(0)
        for w in sorted(graph[v] & group):
            if w == start:
                path = [v]
                while path[-1] != start:
                    path.append(previous[path[-1]])
                return [*reversed(path), start]
            if w not in previous:
                previous[w] = v
                queue.append(w)
    raise AssertionError(f"no circle through {start} in {sorted(group)}")  # a group is strongly connected


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return import_graph(PACKAGES)


def test_the_graph_sees_the_projects_imports(graph):
    """A graph that missed the imports would pass the tests below for nothing: it has every
    module, and the edges of known module- and function-level imports."""
    assert {"bogie_env", "bogie_env.envs.task", "bogie_agents.design.margins", "bogie_agents.evaluation.stability_protocol"} <= set(graph)
    assert "bogie_env.wheel_rail" in graph["bogie_env.envs.task"]  # from ..wheel_rail import ...
    assert "bogie_agents.controllers.lqr" in graph["bogie_agents.design.margins"]  # function-level, in controller_model
    assert "bogie_env.envs.task" in graph["bogie_agents.controllers.lqr"]  # from bogie_env.envs import task as T


def test_no_import_circle_among_the_projects_modules(graph):
    cycles = find_cycles(graph)
    assert not cycles, "import circles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_the_library_imports_nothing_from_the_agents(graph):
    wrong = {m: sorted(t for t in targets if t.startswith("bogie_agents"))
             for m, targets in graph.items() if m.startswith("bogie_env")}  # fmt: skip
    assert not {m: t for m, t in wrong.items() if t}
    for path in PACKAGES["bogie_env"].rglob("*.py"):  # nor by the repository folder's own name
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and not node.level and node.module:
                assert node.module.split(".")[0] not in ("agents", "bogie_agents"), (path, node.module)
            if isinstance(node, ast.Import):
                assert all(a.name.split(".")[0] not in ("agents", "bogie_agents") for a in node.names), path


def test_the_env_imports_no_analysis_module(graph):
    wrong = {m: sorted(t for t in targets if t.startswith("bogie_env.analysis"))
             for m, targets in graph.items() if m.startswith("bogie_env.envs")}  # fmt: skip
    assert not {m: t for m, t in wrong.items() if t}


def _write(folder: Path, files: dict[str, str]) -> None:
    for name, text in files.items():
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_a_planted_function_level_circle_is_found(tmp_path):
    """Three modules in a circle, one edge a function-level relative import, one through a
    subpackage's ``from . import``: the circle is found and named; without the function-level
    import there is none."""
    files = {
        "__init__.py": "",
        "a.py": "from .sub import b\n",
        "sub/__init__.py": "",
        "sub/b.py": "from . import c\n",
        "sub/c.py": "import os\n\ndef late():\n    from ..a import anything\n    return anything\n",
    }
    _write(tmp_path / "pkg", files)
    graph = import_graph({"pkg": tmp_path / "pkg"})
    assert graph["pkg.a"] == {"pkg.sub.b"} and graph["pkg.sub.b"] == {"pkg.sub.c"} and graph["pkg.sub.c"] == {"pkg.a"}
    assert find_cycles(graph) == [["pkg.a", "pkg.sub.b", "pkg.sub.c", "pkg.a"]]
    _write(tmp_path / "pkg", {"sub/c.py": "import os\n"})
    assert find_cycles(import_graph({"pkg": tmp_path / "pkg"})) == []


def test_a_planted_two_module_circle_across_packages_is_found(tmp_path):
    _write(tmp_path / "lib", {"__init__.py": "", "x.py": "def f():\n    import app.y\n"})
    _write(tmp_path / "app", {"__init__.py": "", "y.py": "from lib.x import f\n"})
    graph = import_graph({"lib": tmp_path / "lib", "app": tmp_path / "app"})
    assert find_cycles(graph) == [["app.y", "lib.x", "app.y"]]


#: bogie_agents' subpackages (and its command line) -> the ones each may import (docs/extending.md,
#: "Code layout"): design analyses controllers, evaluation runs both, training trains controllers
#: (a distillation fit may hold their loops' margins: design) and scores them, and only the command line (and ``__main__``, its launcher) sees everything.
LAYERS = {
    "controllers": set(),
    "design": {"controllers"},
    "evaluation": {"controllers", "design"},
    "training": {"controllers", "design", "evaluation"},
    "cli": {"controllers", "design", "evaluation", "training"},
    "__main__": {"cli"},
}
#: The upward imports the layers allow, each inside a function: a controller's own linear model and
#: the robust design's margins use the margins' tools (the module graph above has no circle).
UPWARD = {
    ("bogie_agents.controllers.residual", "bogie_agents.design.margins"),  # ResidualPolicy.controller_model
    ("bogie_agents.controllers.robust", "bogie_agents.design.margins"),  # controller_model, design_margins
    ("bogie_agents.controllers.distilled", "bogie_agents.design.margins"),  # DistilledPolicy.controller_model
}


def _layer(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "bogie_agents" and len(parts) > 1 and parts[1] != "pretrained" else None


def test_bogie_agents_has_its_subpackages_and_a_flat_top():
    """Every module of bogie_agents sits in one of the layers' subpackages, except the package
    itself, its command line and its launcher."""
    modules = [m for m in project_modules(PACKAGES) if m.startswith("bogie_agents")]
    assert {_layer(m) for m in modules} - {None} == set(LAYERS)
    assert {m for m in modules if m.count(".") == 1} == {"bogie_agents.cli", "bogie_agents.__main__", *(f"bogie_agents.{s}" for s in LAYERS if s not in ("cli", "__main__"))}
    assert all(m.count(".") <= 2 for m in modules), "no deeper subpackages"


def test_the_subpackages_import_along_the_layers(graph):
    wrong = sorted(
        f"{m} -> {t}"
        for m, targets in graph.items() if _layer(m)
        for t in targets if _layer(t) and _layer(t) != _layer(m) and _layer(t) not in LAYERS[_layer(m)] and (m, t) not in UPWARD
    )  # fmt: skip
    assert not wrong, "imports against the layers: " + "; ".join(wrong)
    assert not any("bogie_agents.cli" in targets for m, targets in graph.items() if m != "bogie_agents.__main__")


def test_the_allowed_upward_imports_are_function_level_and_still_there(graph):
    """An allowed upward import is one inside a function, never at module level (a module-level
    one would tie the layers together at import time); one that is gone leaves the list."""
    modules = project_modules(PACKAGES)
    for module, target in UPWARD:
        assert target in graph[module], (module, target)
        for node in ast.parse(modules[module].read_text()).body:  # the module-level statements
            if isinstance(node, ast.ImportFrom):
                base = _absolute(module, False, node.level, node.module)
                assert _project_module(base, modules) != target, f"{module} imports {target} at module level"
