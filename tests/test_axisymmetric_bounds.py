"""Certified bounds on axisymmetric models (docs/bounds.md, "Axisymmetric models").

The upper bound integrates the Hencky energy of a P1 field by the vertex rule (the hoop
strain v_r / r varies inside each element), the lower bound is the equilibrium element in
``tau = r sigma`` with the hoop stress constant per element. Checks: the uniaxially
compressed solid cylinder (tests/test_axisymmetric.py) is exact on both sides; the
certificate refuses fields that break one condition; on a family of sphere-indentation
meshes every lower bound lies below every upper bound and the bracket narrows.
"""

from __future__ import annotations

import json
from dataclasses import replace

import clarabel
import numpy as np
import pytest
import scipy.sparse as sp

import elastoplast as ep
from elastoplast.bounds.equilibrium.bound import lower_bound_setup, program_field, solve_program
from elastoplast.bounds.equilibrium.program import lower_bound_program
from elastoplast.bounds.equilibrium.repair import repair_static
from elastoplast.bounds.lower import LowerBoundOptions, lower_bound_kind
from elastoplast.bounds.static import certify_static
from elastoplast.bounds.upper import hencky_energy_density, sub_lattice
from elastoplast.cli.main import main
from elastoplast.errors import InputError
from elastoplast.references.certified import certified_bounds

from test_axisymmetric import A_CYL, E, H, H_CYL, SY, closed_form, cylinder, sphere_problem
from test_cli import write_toml


def exact_energy(q: float) -> float:
    """Pi* of the cylinder under the mean pressure q: the uniaxial Hencky energy times the
    volume, less F U."""
    kappa = max(0.0, q - SY) / H
    W = 0.5 * q**2 / E + SY * kappa + 0.5 * H * kappa**2
    return W * np.pi * A_CYL**2 * H_CYL - q * np.pi * A_CYL**2 * closed_form(q)


@pytest.fixture(scope="module")
def sphere_family():
    """(disc, solution, upper, lower) on three meshes of the sphere indentation."""
    out = []
    for n in (8, 16, 32):
        disc = ep.discretize(ep.problem_from_dict(sphere_problem(divisions=(n, n))))
        sol = ep.solve(disc, method="conic", progress=False)
        out.append((disc, sol, ep.upper_bound(disc, sol), ep.solve_lower_bound(disc)))
    return out


@pytest.mark.parametrize("q", [100.0, 600.0], ids=["elastic", "plastic"])
def test_cylinder_bounds_are_the_closed_form(q):
    disc = ep.discretize(ep.problem_from_dict(cylinder(q * np.pi * A_CYL**2)))
    report = certified_bounds(disc, method="conic", progress=None)
    b, exact = report.bounds, exact_energy(q)
    assert report.certified and report.lower.certificate.worst < 1e-14
    assert b.energy_upper == pytest.approx(exact, rel=1e-12)
    assert b.energy_lower == pytest.approx(exact, rel=1e-9)  # the program's optimum, to its tolerance
    assert report.U_lower <= closed_form(q) <= report.U_upper
    # uniform stress: sigma_thth = 0, and tau = r sigma is sigma_zz = -q times r
    field = report.lower.field
    # (to the interior point's tolerance: the energy is quadratic near its optimum)
    np.testing.assert_allclose(field.hoop, 0.0, atol=1e-4 * q)
    r = disc.mesh.points[disc.mesh.cells, 0]
    np.testing.assert_allclose(field.tau[..., 1], -q * r, atol=1e-4 * q * A_CYL)


def test_vertex_rule_is_an_over_estimate_that_tightens():
    """The sub-triangle rule: each lattice point's count, a bound that falls with k, and
    the centroid rule of the discrete energy below it (Jensen: not an upper bound)."""
    bary, count = sub_lattice(3)
    assert count.sum() == 3 * 9 and np.allclose(bary.sum(axis=1), 1.0)
    disc = ep.discretize(ep.problem_from_dict(sphere_problem(divisions=(8, 8))))
    sol = ep.solve(disc, method="conic", progress=False)
    values = [ep.upper_bound(disc, sol, subdivisions=k).Pi for k in (1, 2, 4, 16)]
    assert all(a > b for a, b in zip(values, values[1:]))
    centroid = float(disc.volumes @ hencky_energy_density(disc.material, disc.strain(disc.free_displacement(np.asarray(sol.u))))) - disc.force * sol.U
    assert centroid < values[-1]
    with pytest.raises(InputError) as info:
        ep.upper_bound(disc, sol, subdivisions=0)
    assert info.value.field == "subdivisions"
    # a candidate with u_r != 0 on the axis is not in H1 of the solid: no bound
    u = np.array(disc.full_displacement(sol.u) if np.ndim(sol.u) == 1 else sol.u, dtype=float).reshape(-1, 2)
    u[disc.mesh.points[:, 0] == 0, 0] = 1e-6
    assert not ep.upper_bound(disc, (u, sol.U)).certified


def test_certificate_refuses_broken_fields():
    disc = ep.discretize(ep.problem_from_dict(sphere_problem(divisions=(6, 6))))
    good = ep.solve_lower_bound(disc)
    assert good.certified and good.certificate.passed
    f = good.field
    r = disc.mesh.points[disc.mesh.cells, 0]
    scale = np.abs(f.tau).max()
    # tau perturbed at a vertex off the axis of one element
    e, a = np.argwhere(r > 0)[len(r) // 2]
    tau = f.tau.copy()
    tau[e, a, 0] += 1e-6 * scale
    cert = certify_static(disc, replace(f, tau=tau))
    assert not cert.passed and "equilibrium" in cert.failed
    # tau != 0 at a vertex on the axis (the rest of the field untouched)
    e, a = np.argwhere(r == 0)[0]
    tau = f.tau.copy()
    tau[e, a, 3] = 1e-6 * scale
    assert "axis" in certify_static(disc, replace(f, tau=tau)).failed
    # a hoop stress that tau's hoop slot does not carry
    hoop = f.hoop.copy()
    hoop[0] += 1e-6 * np.abs(hoop).max()
    assert {"equilibrium", "hoop"} <= set(certify_static(disc, replace(f, hoop=hoop)).failed)
    # the plane field without its radial body force: sigma_thth dropped from the balance
    assert "equilibrium" in certify_static(disc, replace(f, hoop=0 * f.hoop)).failed


def test_a_dropped_balance_row_is_refused():
    """The program with one element's radial balance row left out: its repaired optimum
    satisfies every other row exactly and fails the certificate's equilibrium."""
    disc = ep.discretize(ep.problem_from_dict(sphere_problem(divisions=(6, 6))))
    options = LowerBoundOptions()
    s = lower_bound_setup(disc, options)
    q = s.psi.q / (s.units.displacement * s.units.length)
    prog = lower_bound_program(s.nd, s.topo, s.grads, q, ring=s.ring)
    drop = 2 * (disc.n_elements // 2)  # the radial row of a middle element
    keep = np.setdiff1d(np.arange(prog.A.shape[0]), [drop])
    cut = replace(prog, A=sp.csc_matrix(prog.A[keep]), b=prog.b[keep], n_eq=prog.n_eq - 1,
                  cones=[clarabel.ZeroConeT(prog.n_eq - 1), *prog.cones[1:]])
    x, resid, _ = repair_static(cut, solve_program(disc, cut, options, "clarabel").x)
    assert resid < 1e-12
    cert = certify_static(disc, program_field(s, cut, x, disc.force))
    assert "equilibrium" in cert.failed and "traction_jump" not in cert.failed


def test_every_lower_bound_below_every_upper_bound(sphere_family):
    lowers = [lo.lower for _, _, _, lo in sphere_family]
    uppers = [up.Pi for _, _, up, _ in sphere_family]
    assert all(lo.certified and up.certified for _, _, up, lo in sphere_family)
    assert max(lowers) <= min(uppers)
    gaps = [u - lo for u, lo in zip(uppers, lowers)]
    assert gaps[0] > 2 * gaps[1] > 4 * gaps[2] > 0  # about 4x per halving of h
    assert lowers == sorted(lowers) and uppers == sorted(uppers, reverse=True)


def test_local_gaps_sum_to_the_gap(sphere_family):
    """combine's element and facet terms (vertex rule on both sides, 2 pi on the contact
    facets) are each >= 0 up to round-off and add up to the bracket."""
    from elastoplast.bounds.bracket import combine

    disc, _, up, lo = sphere_family[1]
    b = combine(up, lo)
    total = b.element_gap.sum() + b.facet_gap.sum()
    assert total == pytest.approx(b.energy_gap, rel=1e-8)
    assert b.element_gap.min() > -1e-10 * b.energy_gap and b.facet_gap.min() > -1e-10 * b.energy_gap


def test_lower_bound_choice_and_the_command_line(tmp_path, capsys):
    disc = ep.discretize(ep.problem_from_dict(cylinder(100.0)))
    assert lower_bound_kind(disc, LowerBoundOptions(kind="auto")) == "global"
    with pytest.raises(InputError) as info:
        lower_bound_kind(disc, LowerBoundOptions(kind="local"))
    assert info.value.field == "kind"
    problem = write_toml(tmp_path / "p.toml", sphere_problem(divisions=(8, 8)))
    code = main(["bounds", str(problem), "--lower", "local", "--quiet", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and "--lower" in err and "axisymmetric" in err and len(err.strip().splitlines()) == 1
    code = main(["bounds", str(problem), "--quiet", "--out", str(tmp_path / "b")])
    out = capsys.readouterr().out
    assert code == 0 and "global program, the only one in axisymmetry" in out, out
    summary = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert summary["bounds_certified"] and summary["lower_bound_kind"] == "global"
    assert summary["energy_lower"] <= summary["energy_upper"]
    assert summary["U_lower"] <= summary["U_upper"]


def test_adapt_on_an_axisymmetric_problem(tmp_path, capsys):
    """adapt with the global lower bound: every step certified, the gap falling, the local
    indicators the axisymmetric ones (their sum is the gap); --lower local refused first."""
    problem = write_toml(tmp_path / "p.toml", sphere_problem(divisions=(8, 8)))
    code = main(["adapt", str(problem), "--lower", "local", "--quiet", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and "--lower" in err and "axisymmetric" in err
    result = ep.solve_adaptive(ep.problem_from_dict(sphere_problem(divisions=(8, 8))),
                               ep.AdaptOptions(rtol=0.1, bracket="never", compare_uniform=False, progress=False))
    gaps = [s.gap_rel for s in result.steps]
    assert all(s.certified and s.lower == "global" for s in result.steps)
    assert gaps[-1] <= 0.1 < gaps[0] and result.steps[-1].n_elements > result.steps[0].n_elements
