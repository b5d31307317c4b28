"""What the commands print about a problem and its figures, written once for all of them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from elastoplast.fem.discretize import Discretization, discretize
from elastoplast.problem.definition import problem_from_dict


def discretize_file(path: Path, data: dict) -> Discretization:
    """The discretisation of a problem file's table ``data`` (relative paths against its folder)."""
    return discretize(problem_from_dict(data, base_dir=path.parent))


def problem_line(path: Path, disc: Discretization, what: str) -> str:
    """The one line a command prints on stderr before its work: the problem's size, then ``what``."""
    return (f"{path.name}: {disc.dim}D, {disc.n_elements} elements, {disc.mesh.n_nodes} nodes, "
            f"{disc.n_contact} contact nodes; {what}")
