"""The import rules of docs/architecture.md, checked on the package's source.

Each subpackage is a layer; a module may import (at the top or inside a function) from
its own layer and from the layers before it only. The rules are read from the source
with :mod:`ast`, so a new import that points the wrong way fails here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).parents[1] / "elastoplast"

#: the layers of docs/architecture.md, in order
LAYERS = ["base", "mesh", "problem", "fem", "linalg", "certificate", "solvers", "bounds", "references", "adapt", "io",
          "plots", "studies",
          "cli"]
BASE = {"errors", "limits", "options", "version"}
#: exceptions stated in docs/architecture.md: (importing layer, imported module)
ALLOWED = {("problem", "elastoplast.fem.material")}
#: stated there too: io/ writes what it is given and never computes bounds
FORBIDDEN = {("io", "bounds"), ("io", "references"), ("io", "adapt")}
#: stated there too: bounds/ computes bounds from the solutions it is given and runs no solve
#: (the conic building blocks and the backend adapter serve its own programs); what solves and
#: then bounds is references/
RUNS_SOLVES = {"elastoplast.solvers.registry", "elastoplast.solvers.path", "elastoplast.solvers.newton",
               "elastoplast.solvers.uzawa", "elastoplast.solvers.accelerated", "elastoplast.solvers.plugins"}


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "elastoplast" or len(parts) < 2:
        return None  # the package root: the public API, exempt
    if parts[1] in BASE:
        return "base"
    return parts[1] if parts[1] in LAYERS else None


def package_modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE.parent).with_suffix("")
        name = ".".join(rel.parts)
        out[name.removesuffix(".__init__")] = path
    return out


def imports(path: Path) -> list[tuple[int, str]]:
    """Every ``elastoplast`` module imported anywhere in ``path`` (absolute imports only)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            assert node.level == 0, f"{path}:{node.lineno}: relative import"
            if node.module and node.module.startswith("elastoplast"):
                found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.startswith("elastoplast")]
    return found


MODULES = package_modules()


def test_every_module_has_a_layer():
    unplaced = [m for m in MODULES if m not in ("elastoplast", "elastoplast.__main__") and layer_of(m) is None]
    assert not unplaced, f"modules outside the layers of docs/architecture.md: {unplaced}"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if layer_of(m) is not None))
def test_imports_point_to_earlier_layers(module):
    own = layer_of(module)
    wrong = []
    for line, target in imports(MODULES[module]):
        other = layer_of(target)
        assert other is not None, f"{module}:{line} imports {target} from the package root (import from the module)"
        if (own, target) in ALLOWED:
            continue
        if LAYERS.index(other) > LAYERS.index(own) or (own, other) in FORBIDDEN:
            wrong.append(f"line {line}: {target}")
    assert not wrong, f"{module} ({own}/) imports from later layers: {wrong}"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if layer_of(m) == "bounds"))
def test_bounds_run_no_solve(module):
    runs = [f"line {line}: {target}" for line, target in imports(MODULES[module]) if target in RUNS_SOLVES]
    assert not runs, f"{module} runs solves (that belongs to references/): {runs}"


def test_the_checker_sees_a_wrong_import(tmp_path):
    """The rule can fail: an import of cli/ from fem/ (top level or inside a function) is found."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from elastoplast.cli.main import main\n    return main\n")
    (line, target), = imports(bad)
    assert line == 2 and LAYERS.index(layer_of(target)) > LAYERS.index("fem")


def third_party_imports(path: Path) -> set[str]:
    """The top-level names of every module imported anywhere in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.add(node.module.split(".")[0])
        elif isinstance(node, ast.Import):
            found |= {a.name.split(".")[0] for a in node.names}
    return found


def test_only_plots_imports_matplotlib():
    """docs/architecture.md: plots/ is the one layer drawing figures; the others return values."""
    drawing = sorted(m for m, p in MODULES.items() if "matplotlib" in third_party_imports(p))
    assert drawing and all(m.startswith("elastoplast.plots") for m in drawing), drawing


def test_the_matplotlib_rule_sees_an_import(tmp_path):
    """The rule can fail: a matplotlib import inside a function is found."""
    bad = tmp_path / "bad.py"
    bad.write_text("def f():\n    from matplotlib.figure import Figure\n    return Figure\n")
    assert "matplotlib" in third_party_imports(bad)
