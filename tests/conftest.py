"""Small problems shared by the core tests (2D and 3D, plastic zones present)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

import elastoplast as ep

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"


def cylinder_dict(divisions=(40, 20), **material) -> dict:
    """2D plane-strain cylinder on a clamped block (problems/cylinder_2d.toml, coarser)."""
    data = ep.problem.read_toml(PROBLEMS / "cylinder_2d.toml")
    data["mesh"]["divisions"] = list(divisions)
    data["material"].update(material)
    return data


def sphere_quarter_dict(divisions=(6, 6, 5), **material) -> dict:
    data = ep.problem.read_toml(PROBLEMS / "sphere_quarter_3d.toml")
    data["mesh"]["divisions"] = list(divisions)
    data["material"].update(material)
    return data


def build(data: dict) -> ep.Discretization:
    return ep.discretize(ep.problem_from_dict(copy.deepcopy(data), base_dir=PROBLEMS))


@pytest.fixture(scope="session")
def cylinder_disc() -> ep.Discretization:
    return build(cylinder_dict())


@pytest.fixture(scope="session")
def cylinder_conic(cylinder_disc) -> ep.Solution:
    return ep.solve(cylinder_disc, "conic")


@pytest.fixture(scope="session")
def quarter_disc() -> ep.Discretization:
    return build(sphere_quarter_dict())


@pytest.fixture(scope="session")
def quarter_conic(quarter_disc) -> ep.Solution:
    return ep.solve(quarter_disc, "conic")
