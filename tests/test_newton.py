"""Semismooth Newton and FISTA-accelerated Uzawa (issue 4) against the conic
reference, and the consistent tangent against calculus.

Tolerances: U to 1e-6 relative, stresses to 1e-5 in the energy norm, the same
active contact nodes and plastic elements are the agreement the issue asks of
every method. The conic reference certifies itself to KKT ~1e-9, so the
differences measure both solvers' errors, not only Newton's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from conftest import assert_matches_reference
from elastoplast.fem.material import Material, consistent_tangent, return_mapping
from elastoplast.solvers.newton import NewtonOptions, solve_newton
from elastoplast.problem.definition import problem_from_dict, read_toml

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"
TOL = 1e-10


def small(name: str, divisions: list[int], hardening_over_E: float | None = None) -> ep.Discretization:
    d = read_toml(PROBLEMS / f"{name}.toml")
    d["mesh"]["divisions"] = divisions
    if hardening_over_E is not None:
        d["material"]["hardening"] = hardening_over_E * d["material"]["E"]
    return ep.discretize(problem_from_dict(d, PROBLEMS))


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("hardening", [1e4, 200.0, 0.0])
def test_tangent_matches_central_differences(dim, hardening):
    """d sigma/d eps of the return mapping against central differences.

    The central difference with step h has error O(h^2 |R'''|) + O(eps_mach/h):
    with strains ~1e-2 and h = 1e-7 both sit below 1e-7 of |C|."""
    m = Material(E=200e3, nu=0.3, yield_stress=1000.0, hardening=hardening)
    k = 4 if dim == 2 else 6
    rng = np.random.default_rng(1)
    eps = 1e-2 * rng.standard_normal((40, k))
    if dim == 2:
        eps[:, 2] = 0.0  # plane strain
    eps[:5] *= 1e-3  # some elastic rows too
    _, _, dkappa = return_mapping(m, eps)
    assert np.sum(dkappa > 0) >= 20 and np.sum(dkappa == 0) >= 5
    _, _, tangent = consistent_tangent(m, eps)
    h = 1e-7
    scale = np.abs(m.stiffness(dim)).max()
    for j in range(k):
        if dim == 2 and j == 2:
            continue
        e = np.zeros(k)
        e[j] = h
        fd = (return_mapping(m, eps + e)[0] - return_mapping(m, eps - e)[0]) / (2 * h)
        np.testing.assert_allclose(tangent[:, :, j], fd, atol=1e-7 * scale, rtol=0)


CASES = [
    ("cylinder_2d", [40, 20], None),
    ("cylinder_2d", [40, 20], 1e-3),
    ("sphere_quarter_3d", [6, 6, 6], None),
    ("sphere_quarter_3d", [6, 6, 6], 1e-3),
    ("sphere_block_3d", [10, 10, 6], 1e-3),
]


@pytest.mark.parametrize("name,divisions,hardening", CASES)
def test_newton_agrees_with_conic(name, divisions, hardening):
    disc = small(name, divisions, hardening)
    ref = ep.solve(disc, "conic")
    sol = ep.solve(disc, "newton", tol=TOL)
    assert ref.converged and sol.converged, (ref.message, sol.message)
    assert sol.kkt.worst <= TOL  # the certificate's residuals, recomputed by make_solution
    assert_matches_reference(disc, sol, ref)
    assert sol.plastic.any() and sol.active.sum() > 1  # a real contact problem with a plastic zone


def test_final_iterations_superlinear():
    """Semismooth Newton converges locally superlinearly: once the contact and
    plastic sets are right, each residual ratio is smaller than the last.
    Ratios are taken above 1e-12, where rounding (about 1e-14 here) does not
    yet decide the residual."""
    sol = solve_newton(small("cylinder_2d", [40, 20], 1e-3), NewtonOptions(tol=1e-13))
    worst = [h["kkt_worst"] for h in sol.history if "kkt_worst" in h]
    assert sol.converged and worst[-1] <= 1e-13
    above = [w for w in worst if w > 1e-12]
    ratios = np.array(above[1:]) / np.array(above[:-1])
    assert len(ratios) >= 2
    assert ratios[-1] < ratios[-2] < 1.0, worst
    assert ratios[-1] < 1e-2, worst  # a linearly convergent method would not drop 100x per step here


def test_load_steps_and_splu_give_the_same_solution():
    """Hencky's law is path independent, and the linear solver must not matter:
    both change the route, never the discrete solution (to the tolerance)."""
    disc = small("cylinder_2d", [40, 20])
    a = solve_newton(disc, NewtonOptions(tol=TOL))
    b = solve_newton(disc, NewtonOptions(tol=TOL, load_steps=3, linear_solver="splu"))
    assert a.converged and b.converged
    assert abs(a.U - b.U) <= 1e-8 * abs(a.U)
    np.testing.assert_array_equal(a.active, b.active)


def test_max_iterations_reports_status_and_true_residuals():
    disc = small("cylinder_2d", [40, 20])
    sol = ep.solve(disc, "newton", tol=TOL, max_iter=2)
    assert sol.status is ep.Status.MAX_ITERATIONS
    assert sol.iterations == 2
    assert sol.kkt.worst > TOL
    assert sol.history[-1]["kkt_worst"] == pytest.approx(sol.kkt.worst, rel=1e-6)


FAST_CASES = [
    ("cylinder_2d", [40, 20], 1e-3),
    ("sphere_quarter_3d", [6, 6, 6], None),
    ("sphere_block_3d", [10, 10, 6], 1e-3),
]


@pytest.mark.parametrize("name,divisions,hardening", FAST_CASES)
def test_uzawa_fast_agrees_with_conic(name, divisions, hardening):
    """FISTA-accelerated Uzawa stops on the certificate like plain Uzawa; at
    KKT <= 1e-9 it meets the same agreement as every other method."""
    disc = small(name, divisions, hardening)
    ref = ep.solve(disc, "conic")
    sol = ep.solve(disc, "uzawa-fast", tol=1e-9, max_iter=5000)
    assert sol.converged, sol.message
    assert sol.kkt.worst <= 1e-9
    assert_matches_reference(disc, sol, ref)


def test_uzawa_fast_max_iterations_status():
    sol = ep.solve(small("cylinder_2d", [40, 20]), "uzawa-fast", tol=1e-12, max_iter=3)
    assert sol.status is ep.Status.MAX_ITERATIONS
    assert sol.iterations == 3 and sol.kkt.worst > 1e-12
