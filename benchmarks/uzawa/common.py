"""Problem families of the Uzawa benchmark: the shipped problems with other mesh divisions."""

from __future__ import annotations

from pathlib import Path

import elastoplast as ep
from elastoplast.problem.definition import read_toml

PROBLEMS = Path(__file__).resolve().parents[2] / "problems"


def family(name: str, divisions: list[int], **material) -> ep.Discretization:
    """``problems/<name>.toml`` with ``mesh.divisions`` replaced (and material keys overridden)."""
    data = read_toml(PROBLEMS / f"{name}.toml")
    data["mesh"]["divisions"] = list(divisions)
    data["material"].update(material)
    return ep.discretize(ep.problem_from_dict(data, PROBLEMS))
