"""Small problems shared by the core tests (2D and 3D, plastic zones present), and
the rule that no test writes outside its temporary folder.

Every test runs in its own empty working directory (:func:`in_a_temporary_directory`),
so whatever it, a notebook or a README snippet writes under a relative path lands
there. Repository files are reached through :data:`ROOT`, never through a path
relative to the working directory.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"


@pytest.fixture(autouse=True)
def in_a_temporary_directory(tmp_path, monkeypatch):
    """Run each test with ``tmp_path`` as the working directory (the CLI's default
    ``--out results``, plots and stores written under relative paths go there)."""
    monkeypatch.chdir(tmp_path)


def cylinder_dict(divisions=(40, 20), **material) -> dict:
    """2D plane-strain cylinder on a clamped block (problems/cylinder_2d.toml, coarser)."""
    data = ep.read_toml(PROBLEMS / "cylinder_2d.toml")
    data["mesh"]["divisions"] = list(divisions)
    data["material"].update(material)
    return data


def sphere_quarter_dict(divisions=(6, 6, 5), **material) -> dict:
    data = ep.read_toml(PROBLEMS / "sphere_quarter_3d.toml")
    data["mesh"]["divisions"] = list(divisions)
    data["material"].update(material)
    return data


def energy_error(disc: ep.Discretization, a: ep.Solution, b: ep.Solution) -> float:
    """Relative distance of ``a``'s stresses from ``b``'s in the energy norm [.,.]."""
    from elastoplast.certificate.kkt import energy_norm_sq

    return float(np.sqrt(energy_norm_sq(disc, a.sigma - b.sigma, a.xi - b.xi) / energy_norm_sq(disc, b.sigma, b.xi)))


def assert_matches_reference(disc: ep.Discretization, sol: ep.Solution, ref: ep.Solution) -> None:
    """The agreement issues 3 and 4 ask of every method against the conic
    reference: U to 1e-6 relative, stresses to 1e-5 in the energy norm, the
    same active contact nodes and the same plastic elements."""
    assert abs(sol.U - ref.U) <= 1e-6 * abs(ref.U)
    assert energy_error(disc, sol, ref) <= 1e-5
    np.testing.assert_array_equal(sol.active, ref.active)
    np.testing.assert_array_equal(sol.plastic, ref.plastic)


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
