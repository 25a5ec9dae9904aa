"""The package layers, checked on the source (``ast``, nothing imported): every import, at module level or inside a
function, points down the layers.

    schemas  <-  skills  <-  corpus  <-  services, sim_worker  <-  experiments  <-  cli

- ``schemas/`` (the contract) imports none of the project's other packages;
- ``skills/`` (the science) imports only ``schemas``: no service, no simulator, and no test-data generator;
- ``corpus/`` (demonstrations with known ground truth) imports only ``schemas`` and ``skills``;
- nothing below ``cli/`` imports from ``cli`` (the console script is the top; a child process started as
  ``python -m cli.main`` is a command line, not an import);
- ``services/`` and ``sim_worker/`` import nothing from ``experiments/`` (the runners sit on top of them), nor
  from each other (they meet on the bus, through the ``schemas`` contract).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FORBIDDEN: dict[str, set[str]] = {
    "schemas": {"skills", "corpus", "services", "sim_worker", "experiments", "cli", "benchmarks"},
    "skills": {"corpus", "services", "sim_worker", "experiments", "cli", "benchmarks"},
    "corpus": {"services", "sim_worker", "experiments", "cli", "benchmarks"},
    "services": {"sim_worker", "experiments", "cli", "benchmarks"},
    "sim_worker": {"services", "experiments", "cli", "benchmarks"},
    "experiments": {"cli", "benchmarks"},
}


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
