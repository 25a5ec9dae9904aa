"""The package layers, checked on the source (``ast``, nothing imported): every import, at module level or inside a
function, points down the layers.

    schemas  <-  skills  <-  corpus, execution  <-  services, sim_worker  <-  experiments  <-  cli

- ``schemas/`` (the contract) imports none of the project's other packages;
- ``skills/`` (the science) imports only ``schemas``: no service, no simulator, and no test-data generator;
- ``corpus/`` (demonstrations with known ground truth) imports only ``schemas`` and ``skills``;
- ``execution/`` (an execution apart from any physics engine: plans, contact detection, surface following, metrics,
  telemetry, the robot interface) imports only ``schemas`` and ``skills``: no engine, no bus, no test data;
- nothing below ``cli/`` imports from ``cli`` (the console script is the top; a child process started as
  ``python -m cli.main`` is a command line, not an import);
- ``services/`` and ``sim_worker/`` import nothing from ``experiments/`` (the runners sit on top of them), nor
  from each other (they meet on the bus, through the ``schemas`` contract);
- no module imports itself through others: the graph of every import between the repository's modules (lazy ones
  inside functions included, ``from pkg import mod`` counted as an import of ``pkg.mod``) has no cycle.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterable
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FORBIDDEN: dict[str, set[str]] = {
    "schemas": {"skills", "corpus", "execution", "services", "sim_worker", "experiments", "cli", "benchmarks"},
    "skills": {"corpus", "execution", "services", "sim_worker", "experiments", "cli", "benchmarks"},
    "corpus": {"execution", "services", "sim_worker", "experiments", "cli", "benchmarks"},
    "execution": {"corpus", "services", "sim_worker", "experiments", "cli", "benchmarks"},
    "services": {"sim_worker", "experiments", "cli", "benchmarks"},
    "sim_worker": {"services", "experiments", "cli", "benchmarks"},
    # The MuJoCo engine: sim_worker's engine-free data (world_config, robot_model, geometry, sensor), never PyBullet.
    "sim_mujoco": {"services", "experiments", "cli", "benchmarks", "pybullet"},
    "experiments": {"cli", "benchmarks"},
}
PACKAGES = (
    "schemas",
    "skills",
    "corpus",
    "execution",
    "services",
    "sim_worker",
    "sim_mujoco",
    "experiments",
    "cli",
    "benchmarks",
)


def imported_packages(source: str, package: tuple[str, ...]) -> list[tuple[int, str]]:
    """(line, top-level package) of every import in ``source``, a module of ``package`` (``("services", "api")``);
    relative imports resolved against it."""
    tree = ast.parse(source)
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name.split(".")[0]) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                found.append((node.lineno, base[0] if base else (node.module or "").split(".")[0]))
            elif node.module:
                found.append((node.lineno, node.module.split(".")[0]))
    return found


def violations(layer: str) -> list[str]:
    forbidden = FORBIDDEN[layer]
    return [
        f"{path.relative_to(REPO)}:{line} imports {target}"
        for path in sorted((REPO / layer).rglob("*.py"))
        for line, target in imported_packages(path.read_text(), path.relative_to(REPO).parts[:-1])
        if target in forbidden
    ]


@pytest.mark.parametrize("layer", sorted(FORBIDDEN))
def test_imports_point_down_the_layers(layer: str) -> None:
    assert (REPO / layer / "__init__.py").exists(), f"{layer}/ is not a package"
    assert violations(layer) == [], f"{layer}/ may not import from {sorted(FORBIDDEN[layer])}"


def test_the_check_sees_lazy_and_relative_imports() -> None:
    """The walker finds imports inside functions and resolves ``from .. import x`` against the package."""
    source = "def f():\n    from cli.main import main\n\nfrom ..routes import health\nimport services.app as a\n"
    found = imported_packages(source, ("services", "api", "routes"))
    assert sorted(found) == [(2, "cli"), (4, "services"), (5, "services")]
    assert imported_packages("from . import x\n", ("skills",)) == [(1, "skills")]


def module_graph(root: Path, packages: Iterable[str]) -> dict[str, set[str]]:
    """Module (dotted name) -> the repository's modules it imports, from the source of ``packages`` under ``root``."""
    files = [path for package in packages for path in (root / package).rglob("*.py")]
    paths = {path: path.relative_to(root).with_suffix("").parts for path in files}
    names = {p: ".".join(parts[:-1] if parts[-1] == "__init__" else parts) for p, parts in paths.items()}
    modules = set(names.values())

    def resolve(name: str) -> str | None:
        while name and name not in modules:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for path, name in names.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        targets: set[str | None] = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                targets |= {resolve(alias.name) for alias in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = ".".join(package[: len(package) - node.level + 1]) if node.level else ""
                module = ".".join(part for part in (base, node.module or "") if part)
                targets |= {resolve(f"{module}.{a.name}" if f"{module}.{a.name}" in modules else module)
                            for a in node.names}  # fmt: skip
        graph[name] = {t for t in targets if t is not None and t != name}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[set[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[set[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            successor = next(successors, None)
            if successor is not None:
                if successor not in index:
                    index[successor] = low[successor] = len(index)
                    stack.append(successor)
                    on_stack.add(successor)
                    work.append((successor, iter(sorted(graph[successor]))))
                elif successor in on_stack:
                    low[node] = min(low[node], index[successor])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    cycles.append(component)
    return cycles


def test_no_import_cycles() -> None:
    cycles = [sorted(c) for c in import_cycles(module_graph(REPO, PACKAGES))]
    assert cycles == [], f"import cycles: {cycles}"


def test_the_cycle_check_finds_a_lazy_cycle_through_a_package(tmp_path: Path) -> None:
    """``a.main`` imports ``a.cmd`` at the top, ``a.cmd`` imports ``main`` lazily as ``from a import main``: one
    cycle; ``b`` imports ``a`` without a way back: none."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "__init__.py").write_text("")
    (tmp_path / "a" / "main.py").write_text("from . import cmd\n")
    (tmp_path / "a" / "cmd.py").write_text("def f():\n    from a import main\n")
    (tmp_path / "b" / "__init__.py").write_text("import a.main\n")
    graph = module_graph(tmp_path, ("a", "b"))
    assert graph["a.cmd"] == {"a.main"} and graph["a.main"] == {"a.cmd"} and graph["b"] == {"a.main"}
    assert import_cycles(graph) == [{"a.main", "a.cmd"}]


def test_the_services_import_nothing_from_the_api_above_them() -> None:
    """``services/api/`` (routes, dependencies, error answers, middleware) sits on the services: the learner pool, the
    settings, the Foxglove gate take nothing from it (what both HTTP servers share is ``services/http_rules.py``).
    ``services/app.py`` builds the app from it, and is the one module that may."""
    graph = module_graph(REPO, ["services"])
    upward = {
        f"{module} imports {target}"
        for module, targets in graph.items()
        if not module.startswith("services.api") and module != "services.app"
        for target in targets
        if target.startswith("services.api")
    }
    assert upward == set()


IO_CALLS = frozenset({"open", "read_text", "read_bytes", "write_text", "write_bytes", "getenv"})
"""Calls that read or write files or the environment (``os.environ`` is found as an attribute)."""


def io_uses(source: str) -> list[tuple[int, str]]:
    """(line, what) of every file or environment access in ``source``: a call of :data:`IO_CALLS`, ``os.environ``."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call):
            name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
            if name in IO_CALLS:
                found.append((node.lineno, f"{name}()"))
        elif isinstance(node, ast.Attribute) and node.attr == "environ":
            found.append((node.lineno, "environ"))
    return sorted(found)


def test_the_contract_reads_no_file_and_no_environment() -> None:
    """``schemas/`` is the contract: a process's files and environment are read by the services, the worker and the
    command line, and handed to it (e.g. ``BusSecurity.from_env(os.environ)``)."""
    uses = [f"{path.relative_to(REPO)}:{line} {what}" for path in sorted((REPO / "schemas").rglob("*.py"))
            for line, what in io_uses(path.read_text())]  # fmt: skip
    assert uses == []
    assert io_uses("import os\nx = os.environ.get('A')\nopen('f')\nPath('p').read_text()\n") == [
        (2, "environ"), (3, "open()"), (4, "read_text()")
    ]  # fmt: skip


CONSTANT = re.compile(r"_?[A-Z][A-Z0-9]*(?:_[A-Z0-9]+)*")
"""An UPPER_CASE name (a constant), private (``_PHASES``) or not."""
PRODUCT = tuple(package for package in PACKAGES if package != "benchmarks")
"""The packages whose constants have one home each. The benchmarks are scripts, each with its own report's private
names (``SECTION``, ``COMMAND``, ``ROOT``: the file each writes, how it is run), not the product's constants."""
CONSTANTS_TWICE_ALLOWED: dict[str, set[str]] = {}
"""Constants assigned in more than one module for now, with the modules: each entry says why and until when."""


def assigned_constants(source: str) -> set[str]:
    """The UPPER_CASE names ``source`` assigns at module level (``A = ...``, ``A: T = ...``, ``A, B = ...``)."""
    names = set()
    for node in ast.parse(source).body:
        targets = (
            node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        )
        names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name) and CONSTANT.fullmatch(n.id)}
    return names


def constant_homes(root: Path, packages: Iterable[str]) -> dict[str, set[str]]:
    """Each constant assigned in more than one module of ``packages`` under ``root``, with those modules (paths)."""
    homes: dict[str, set[str]] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            for name in assigned_constants(path.read_text()):
                homes.setdefault(name, set()).add(path.relative_to(root).as_posix())
    return {name: modules for name, modules in homes.items() if len(modules) > 1}


def test_every_constant_has_one_home() -> None:
    """A constant is assigned in one product module and imported where it is used: two copies drift apart (the
    importer's rate limit and the learner's), and two meanings under one name mislead a reader (a poll period of
    0.05 s and one of 0.5 s)."""
    assert constant_homes(REPO, PRODUCT) == CONSTANTS_TWICE_ALLOWED


def test_the_constant_check_sees_annotated_tuple_and_private_constants(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "x.py").write_text("A: int = 1\nB, _C = 2, 3\nlower = 4\nD_e = 5\ndef f():\n    E = 6\n")
    (tmp_path / "a" / "y.py").write_text("from a.x import A\nB = 2\n_C = 3\nE = 6\n")
    assert assigned_constants((tmp_path / "a" / "x.py").read_text()) == {"A", "B", "_C"}
    assert constant_homes(tmp_path, ("a",)) == {"B": {"a/x.py", "a/y.py"}, "_C": {"a/x.py", "a/y.py"}}
