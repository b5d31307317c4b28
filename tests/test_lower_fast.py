"""The lower bound through SCS (``LowerBoundOptions(solver="scs")``) against Clarabel.

Where the numbers come from:
* "cannot beat the best field": every certified field has J >= J_opt (the optimum of
  the equilibrium-element program on the mesh), and Clarabel's repaired field has J
  within its relative gap tolerance ip_tol = 1e-9 of J_opt (the repair moves it by its
  residuals, of the same size): so -J_scs <= -J_clarabel + 1e-8 |J|;
* "as tight": SCS stops when its relative primal and dual residuals and duality gap are
  below eps; the repair moves its point by its residuals, which changes J by the same
  relative order. The tests allow 100 eps for the scalings of SCS's norms;
* patch tests: the uniaxial-strain closed form (tests/test_patch.py, a uniform stress
  lies in the equilibrium element, so the program's optimum is Pi* itself);
* H = 0: the SCS program lowers the yield stress by the margin m; the optimum v(s) of
  the program as a function of the yield stress s is convex and non-increasing (the set
  {(tau, s): vm(tau) <= s} is convex), so with s0 = r sigma_y, r = F / F_lower (r times
  the certified limit field carries F at yield stress r sigma_y, so v(s0) <= J of it):
  v((1 - m) sigma_y) - v(sigma_y) <= m / (1 - r) (v(s0) - v(sigma_y)).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import build, cylinder_dict, sphere_quarter_dict
from test_equilibrium import closed_form_energy, patch_force
from test_patch import E, H, NU, SY, patch_problem

import elastoplast as ep
from elastoplast.bounds.static import CERTIFY_TOL, StaticField, dual_energy
from elastoplast.bounds.lower import CLARABEL_MAX_ELEMENTS, LOWER_BOUND_MAX_ELEMENTS, LowerBound, LowerBoundOptions, SCS_FROM_ELEMENTS_3D, check_lower_bound_size, lower_bound_solver
from elastoplast.bounds.equilibrium.bound import SCS_YIELD_MARGIN_PER_EPS, yield_margin, solve_lower_bound, static_limit_load
from elastoplast.fem.material import von_mises

EPS = 1e-6  # SCS's tolerance in these tests (the default of LowerBoundOptions.scs_eps)
SCS = LowerBoundOptions(solver="scs", scs_eps=EPS)
CLARABEL = LowerBoundOptions(solver="clarabel")
#: Clarabel's field is optimal to its gap tolerance 1e-9; 10x for the repair
CLARABEL_SLACK = 1e-8
#: SCS's field is optimal to about its tolerance; 100x for the scalings of its norms
SCS_SLACK = 100 * EPS


def assert_as_tight(scs: LowerBound, ref: LowerBound) -> None:
    assert scs.certified, scs.message
    assert ref.certified, ref.message
    assert scs.solver == "scs" and ref.solver == "clarabel"
    assert "SCS: solved" in scs.message
    assert scs.certificate.worst <= CERTIFY_TOL
    assert -scs.J <= -ref.J + CLARABEL_SLACK * abs(ref.J)  # no field beats the optimum
    assert scs.J - ref.J <= SCS_SLACK * abs(ref.J)


@pytest.mark.parametrize("case", ["cylinder_2d", "quarter_3d"])
def test_scs_bound_is_certified_and_as_tight_as_clarabel(case):
    """2D plane strain under a cylinder; the 3D quarter sphere (two symmetry planes, a
    curved obstacle); both with a plastic zone."""
    disc = build(cylinder_dict(divisions=(24, 12)) if case == "cylinder_2d" else sphere_quarter_dict(divisions=(3, 3, 3)))
    scs, ref = solve_lower_bound(disc, SCS), solve_lower_bound(disc, CLARABEL)
    assert_as_tight(scs, ref)
    assert np.any(von_mises(scs.field.tau.reshape(-1, disc.k)) > disc.material.yield_stress)  # plastic
    assert scs.local.facet_force.sum() == pytest.approx(disc.force, rel=1e-13)  # the repaired field carries F
    # weak duality against the P1 solution (tests/test_equilibrium.py: value_D >= -J for any certified field)
    assert -scs.J <= ep.solve(disc, "conic").value_D


@pytest.mark.parametrize("dim", [2, 3])
def test_scs_patch_bound_is_the_closed_form(dim):
    m = ep.Material(E, NU, SY, H)
    F = patch_force(dim, 3.0, m)  # plastic
    disc = ep.discretize(patch_problem(dim, F))
    lb = solve_lower_bound(disc, SCS)
    _, Pi = closed_form_energy(dim, F, m)
    assert lb.certified, lb.message
    assert -lb.J <= Pi + 1e-12 * abs(Pi)  # a bound, to round-off
    assert Pi - (-lb.J) <= SCS_SLACK * abs(Pi)


def test_scs_elastic_first():
    """A yield stress far above the stresses: the program is first solved without the
    cones (elastic_first), with SCS as with Clarabel."""
    disc = build(cylinder_dict(divisions=(16, 8), yield_stress=1e6))
    assert_as_tight(solve_lower_bound(disc, SCS), solve_lower_bound(disc, CLARABEL))


def small_punch(F: float = 1.0) -> ep.Discretization:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the perfect-plasticity warning
        return ep.discretize(ep.problem_from_dict({
            "mesh": {"generator": "rectangle", "size": [8.0, 4.0], "divisions": [8, 4], "contact_radius": 1.0,
                     "pattern": "crossed"},
            "material": {"E": 200e3, "nu": 0.3, "yield_stress": 250.0, "hardening": 0.0},
            "obstacle": {"shape": "flat"},
            "load": {"force": F},
        }))


def test_scs_limit_load_and_perfect_plasticity():
    disc = small_punch()
    ref = static_limit_load(disc, CLARABEL)
    lim = static_limit_load(disc, SCS)
    assert ref.certified and lim.certified, lim.message
    assert lim.solver == "scs"
    # the certified F_lower of any field is at most the program's optimum, which Clarabel finds to 1e-9
    assert lim.F_lower <= ref.F_lower * (1 + CLARABEL_SLACK)
    assert lim.F_lower >= ref.F_lower * (1 - SCS_SLACK)

    r = 0.9
    loaded = disc.with_force(r * ref.F_lower)
    scs, clar = solve_lower_bound(loaded, SCS), solve_lower_bound(loaded, CLARABEL)
    assert scs.certified and clar.certified, scs.message
    assert -scs.J <= -clar.J + CLARABEL_SLACK * abs(clar.J)
    # the margin's cost (module docstring): r times the limit field carries F at yield stress r sigma_y
    scaled = StaticField(r * ref.field.tau, ref.field.eta, ref.field.contact_facets, r * ref.field.lam,
                            r * ref.field.force)
    v_s0 = dual_energy(loaded, scaled)
    margin = yield_margin("scs", SCS)
    assert margin == pytest.approx(SCS_YIELD_MARGIN_PER_EPS * EPS)
    allowed = margin / (1 - r) * (v_s0 - clar.J) + SCS_SLACK * abs(clar.J)
    assert scs.J - clar.J <= allowed
    # above the limit load SCS proves infeasibility too
    with pytest.raises(ep.InputError, match="load.force"):
        solve_lower_bound(disc.with_force(1.05 * ref.F_lower), SCS)


def test_solver_choice():
    quarter = build(sphere_quarter_dict(divisions=(3, 3, 3)))
    cylinder = build(cylinder_dict(divisions=(8, 4)))
    auto = LowerBoundOptions()
    assert lower_bound_solver(cylinder, auto) == "clarabel"
    assert quarter.n_elements < SCS_FROM_ELEMENTS_3D
    assert lower_bound_solver(quarter, auto) == "clarabel"
    assert lower_bound_solver(quarter, SCS) == "scs"
    larger = build(sphere_quarter_dict(divisions=(5, 5, 4)))
    assert larger.n_elements >= SCS_FROM_ELEMENTS_3D
    assert lower_bound_solver(larger, auto) == "scs"
    assert lower_bound_solver(larger, auto, limit=True) == "clarabel"
    with pytest.raises(ep.InputError, match="solver"):
        LowerBoundOptions(solver="admm")
    with pytest.raises(ep.InputError, match="scs_eps"):
        LowerBoundOptions(scs_eps=0.0)


def test_size_limit_follows_the_solver(monkeypatch):
    """The limit-load program runs on Clarabel, whose size limit is lower than SCS's."""
    disc = build(sphere_quarter_dict(divisions=(5, 5, 4)))
    monkeypatch.setitem(CLARABEL_MAX_ELEMENTS, 3, disc.n_elements - 1)
    check_lower_bound_size(disc, LowerBoundOptions())  # the energy program on SCS: accepted
    with pytest.raises(ep.InputError, match="clarabel is limited to"):
        check_lower_bound_size(disc, LowerBoundOptions(), limit=True)
    with pytest.raises(ep.InputError, match="mesh"):
        solve_lower_bound(disc, CLARABEL)
    monkeypatch.setitem(LOWER_BOUND_MAX_ELEMENTS, 3, disc.n_elements - 1)
    with pytest.raises(ep.InputError, match="scs is limited to"):
        check_lower_bound_size(disc, LowerBoundOptions())
    check_lower_bound_size(disc, LowerBoundOptions(max_elements=disc.n_elements))  # the option overrides
