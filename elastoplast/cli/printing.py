"""What the commands print about a problem and its figures, written once for all of them."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from elastoplast.fem.discretize import Discretization, discretize
from elastoplast.problem.definition import problem_from_dict


def figure(value: Any, spec: str) -> str:
    """A printed figure; ``n/a`` for one that is not a finite number (a diverged run's NaN)."""
    try:
        return format(value, spec) if math.isfinite(value) else "n/a"
    except (TypeError, ValueError):
        return "n/a"


def discretize_file(path: Path, data: dict) -> Discretization:
    """The discretisation of a problem file's table ``data`` (relative paths against its folder)."""
    return discretize(problem_from_dict(data, base_dir=path.parent))


def problem_line(path: Path, disc: Discretization, what: str) -> str:
    """The one line a command prints on stderr before its work: the problem's size, then ``what``."""
    return (f"{path.name}: {disc.dim}D, {disc.n_elements} elements, {disc.mesh.n_nodes} nodes, "
            f"{disc.n_contact} contact nodes; {what}")
