"""Issue 10 on sequences of meshes: bounds from different meshes of one problem (docs/bounds.md).

Where every asserted number comes from:

* weak duality: ``-J(τ, η, λ) <= Π* <= Π(v, V)`` for every admissible stress field
  and every ``(v, V)`` in K, whichever meshes they come from, as long as the meshes
  bound the same continuum problem (the same Γ0, clamped part and symmetry planes).
  Bisection refinement (:func:`elastoplast.refine`) replaces each facet group by its
  refinement, so a refined sequence keeps them exactly;
* nested spaces: the P1 space of a bisection refinement contains the coarse one, so
  the corrected coarse candidate of the upper bound, being in K, is in the fine
  discrete set K_h (non-penetration at the fine nodes): ``Π_h*(F) <= hi_H(F)``. The
  coarse equilibrium field, restricted to the fine elements, is a fine equilibrium
  field (linear per element, tractions continuous, yield at the fine vertices by
  convexity of D) whose obstacle term ``∫ λ I_h ψ`` is at most ``∫ λ I_H ψ`` (ψ
  convex: the fine interpolant lies below the coarse one), so the fine lower bound is
  at least the coarse one, up to the interior point's tolerance;
* convex ψ on nested contact facets: for ``(v, V)`` in the fine K_h, ``v_d - V + I_h ψ``
  is linear on each fine facet and >= 0 at its vertices and ``I_H ψ >= I_h ψ``, so weak
  duality with the coarse obstacle weights gives ``Π_h*(F') >= lo_H(F')`` at any load;
* concavity: ``Π_h*(F)`` is a minimum of functions affine in F, with supergradient
  ``-U_h(F)``: ``Π_h*(F ± δ) <= Π_h*(F) ∓ δ U_h(F)``. With the two points above,
  ``(lo_H(F - δ) - hi_H(F)) / δ <= U_h(F) <= (hi_H(F) - lo_H(F + δ)) / δ``: the U
  bracket of a mesh contains the discrete U of the mesh itself and of every nested
  finer mesh (U_h to the conic solver's accuracy, KKT residuals near 1e-9, far inside
  the margins here);
* the patch test: the uniaxial-strain closed form of tests/test_patch.py (energy and
  U; the exact solution is P1 with a uniform stress, so both bounds attain Π*);
* symmetry: a half model on ``x >= 0`` with the symmetry plane ``x = 0`` and load
  F/2, on the right half of a mirror-symmetric mesh, has ``Π*_half = Π*_full / 2``:
  mirroring an admissible half field gives a full one of twice the energy, and
  symmetrising an admissible full field keeps it admissible without raising its
  convex energy. The same holds for both discrete programs (lower bound and (2.1))
  on the mirrored meshes, so both bounds of the full model are twice the half
  model's, to the solvers' tolerances;
* one ψ written twice: ``0.01 (x² + y²)`` is the paraboloid of radius 50, so its
  interval-enclosed ``expression`` and the ``paraboloid`` bound the same Π*.

The tolerance ``LOWER_SLACK`` on "the fine lower bound is at least the coarse one" is
a hundred times Clarabel's relative gap tolerance of the lower bound
(``LowerBoundOptions.ip_tol = 1e-9``): the optimum is reached only to it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from conftest import build, cylinder_dict, sphere_quarter_dict
from test_equilibrium import closed_form_energy
from test_patch import E, H, NU, SY, patch_problem, uniaxial_strain

import elastoplast as ep
from elastoplast.bounds.bracket import BoundsReport
from elastoplast.references.certified import certified_bounds, energy_bounds
from elastoplast.bounds.upper import contact_facets
from elastoplast.bounds.static import CERTIFY_TOL
from elastoplast.mesh.topology import facet_measure

LOWER_SLACK = 1e-7


def refined_sequence(disc: ep.Discretization, marks: list[str]) -> list[ep.Discretization]:
    """``disc`` and one bisection refinement per entry of ``marks``: ``"all"`` refines
    every element, ``"contact"`` the elements with a node on Γ0. Every mesh is nested
    in the next and keeps the facet groups."""
    mesh, state, out = disc.mesh, None, [disc]
    for how in marks:
        last = out[-1]
        if how == "all":
            marked = np.ones(last.n_elements, dtype=bool)
        else:
            marked = np.isin(last.mesh.cells, last.contact_nodes).any(axis=1)
        mesh, state, _ = ep.refine(mesh, marked, state)
        out.append(ep.discretize(replace(disc.problem, mesh=mesh)))
    return out


def bound_sequence(discs: list[ep.Discretization]) -> list[tuple[ep.Solution, BoundsReport]]:
    """The P1 solution and the certified bounds of every mesh; the U bracket on the
    coarsest only (the finer meshes' U_h are checked against it)."""
    out = []
    for i, disc in enumerate(discs):
        sol = ep.solve(disc, "conic")
        assert sol.converged, sol.message
        out.append((sol, certified_bounds(disc, sol, bracket=i == 0)))
    return out


def check_sequence(results: list[tuple[ep.Solution, BoundsReport]]) -> None:
    """The three properties of a nested sequence (module docstring)."""
    for _, rep in results:
        assert rep.certified, (rep.upper.message, rep.lower.message)
    lowers = np.array([rep.bounds.energy_lower for _, rep in results])
    uppers = np.array([rep.bounds.energy_upper for _, rep in results])
    # weak duality: every lower bound below every upper bound, all pairs of meshes
    assert lowers.max() <= uppers.min()
    assert np.all(lowers[:, None] <= uppers[None, :])
    # concavity + nested spaces: the coarsest U bracket holds every mesh's U_h
    coarse = results[0][1]
    assert coarse.bracket_certified
    for sol, _ in results:
        assert coarse.U_lower <= sol.U <= coarse.U_upper
    # nested spaces: the lower bound does not fall; the gap shrinks (the upper side
    # by a priori convergence, its corrections being O(h^2): not a theorem)
    assert np.all(np.diff(lowers) >= -LOWER_SLACK * np.abs(lowers[:-1]))
    gaps = uppers - lowers
    assert np.all(np.diff(gaps) < 0)


@pytest.fixture(scope="module")
def cylinder_sequence():
    """2D: the graded cylinder at 16 x 8 (256 triangles), refined everywhere (1024),
    then next to Γ0 (1156)."""
    discs = refined_sequence(build(cylinder_dict(divisions=(16, 8))), ["all", "contact"])
    return discs, bound_sequence(discs)


@pytest.fixture(scope="module")
def sphere_sequence():
    """3D: the quarter sphere (two symmetry planes) at 2 x 2 x 2 (48 tetrahedra, Γ0
    widened to the facets within 3 mm so that it is not empty), refined next to Γ0."""
    data = sphere_quarter_dict(divisions=(2, 2, 2))
    data["mesh"]["contact_radius"] = 3.0
    discs = refined_sequence(build(data), ["contact"])
    return discs, bound_sequence(discs)


def test_nested_2d_sequence_bounds_are_ordered_bracket_u_and_converge(cylinder_sequence):
    discs, results = cylinder_sequence
    assert [d.n_elements for d in discs][:2] == [256, 1024]  # "all": 4 children per triangle
    # the refined meshes keep Γ0: the same total length (a union of the coarse facets)
    length = [facet_measure(d.mesh.points[contact_facets(d)]).sum() for d in discs]
    assert np.allclose(length, length[0], rtol=1e-14)
    check_sequence(results)


def test_nested_3d_sequence_bounds_are_ordered_bracket_u_and_converge(sphere_sequence):
    discs, results = sphere_sequence
    area = [facet_measure(d.mesh.points[contact_facets(d)]).sum() for d in discs]
    assert np.allclose(area, area[0], rtol=1e-14)
    assert discs[1].n_elements > discs[0].n_elements
    check_sequence(results)


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("stress_ratio", [0.5, 3.0], ids=["elastic", "plastic"])
def test_patch_test_report_is_the_closed_form(dim, stress_ratio):
    """What the ``bounds`` command reports (:func:`certified_bounds`) on the patch test:
    lower = upper = the closed form to 1e-8, and the U bracket holds the closed-form U."""
    m = ep.Material(E, NU, SY, H)
    area = 3.0 if dim == 2 else 6.0
    F = stress_ratio * (m.lam + 2 * m.mu) * SY / (2 * m.mu) * area  # times the first-yield load
    disc = ep.discretize(patch_problem(dim, F))
    _, Pi = closed_form_energy(dim, F, m)
    U = uniaxial_strain(F / area, m)[0] * 2.0  # block height 2
    rep = certified_bounds(disc)
    b = rep.bounds
    assert rep.certified
    assert b.energy_lower == pytest.approx(Pi, rel=1e-8)
    assert b.energy_upper == pytest.approx(Pi, rel=1e-8)
    # both sides attain the exact value, so their order is decided by round-off: the
    # certificate admits fields within CERTIFY_TOL (relative) of admissibility
    assert b.energy_lower <= b.energy_upper + CERTIFY_TOL * abs(b.energy_upper)
    assert rep.U_lower <= U <= rep.U_upper


def half_and_full_cylinder(n: int) -> tuple[ep.Discretization, ep.Discretization]:
    """The graded cylinder block (40 x 20, 2n x n divisions) and its right half
    (20 x 20, n x n, symmetry plane x = 0, load F/2): the half mesh is the right half of
    the full one (same graded nodes, no reflected layers right of the centre)."""
    full = cylinder_dict(divisions=(2 * n, n))
    half = cylinder_dict(divisions=(n, n))
    half["mesh"].update(size=[20.0, 20.0], origin=[0.0, 0.0], contact_center=[0.0])
    half["boundary"] = {"clamped": ["xmax", "top"], "contact": ["contact"], "fix_component": {"x": ["xmin"]}}
    half["load"]["force"] = full["load"]["force"] / 2
    return build(half), build(full)


def test_symmetry_plane_bounds_half_the_full_model():
    half, full = half_and_full_cylinder(8)
    assert 2 * half.n_elements == full.n_elements
    right = full.mesh.points[:, 0] >= 0
    np.testing.assert_allclose(np.unique(full.mesh.points[right], axis=0), np.unique(half.mesh.points, axis=0))
    bh, bf = energy_bounds(half), energy_bounds(full)
    assert bh.bounds_certified and bf.bounds_certified
    # weak duality across the two models (Π*_full = 2 Π*_half)
    assert 2 * bh.energy_lower <= bf.energy_upper
    assert bf.energy_lower <= 2 * bh.energy_upper
    # the programs themselves are mirror images: equal to ten times the interior
    # point's relative tolerance (ip_tol = 1e-9)
    assert bf.energy_lower == pytest.approx(2 * bh.energy_lower, rel=1e-8)
    assert bf.energy_upper == pytest.approx(2 * bh.energy_upper, rel=1e-8)


def test_expression_and_paraboloid_bound_the_same_energy_in_3d():
    """A quarter model (two symmetry planes) under a paraboloid of radius 50, and the
    same ψ as the expression ``0.01*(x**2 + y**2)`` (interval enclosure): both brackets
    certified, and each lower bound below the other's upper bound."""
    data = sphere_quarter_dict(divisions=(3, 3, 3))
    data["obstacle"] = {"shape": "paraboloid", "radius": 50.0}
    parab = build(data)
    data["obstacle"] = {"shape": "expression", "expression": "0.01*(x**2 + y**2)"}
    expr = build(data)
    np.testing.assert_allclose(expr.psi, parab.psi, rtol=1e-15)
    bp, be = energy_bounds(parab), energy_bounds(expr)
    assert bp.bounds_certified and be.bounds_certified
    for lo in (bp.energy_lower, be.energy_lower):
        for hi in (bp.energy_upper, be.energy_upper):
            assert lo <= hi


def test_u_bracket_near_the_limit_load_with_perfect_plasticity():
    """H = 0, F = 0.9 F_lower with F_lower this mesh's certified static limit load: the
    equilibrium element carries F (the energy bracket exists), and a U bracket exists for
    any delta < F_lower - F. The discrete U_h of the same mesh lies in it (the module
    docstring's nested-spaces and concavity argument, a mesh being nested in itself;
    with H = 0 U_h may not be unique, and every minimiser's U is a supergradient)."""
    import warnings

    from test_limit_load import punch

    from elastoplast.bounds.equilibrium.bound import static_limit_load

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the perfect-plasticity warning
        disc = punch("crossed")
    lim = static_limit_load(disc)
    assert lim.certified
    disc = disc.with_force(0.9 * lim.F_lower)
    sol = ep.solve(disc, "conic")
    rep = certified_bounds(disc, sol)
    assert rep.certified
    assert rep.U_lower <= sol.U <= rep.U_upper
