"""Uzawa's method (issue 3) against the conic reference, the paper's bounds and
the optimality conditions of its two steps."""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from conftest import assert_matches_reference, energy_error
from elastoplast.certificate.kkt import gaps
from elastoplast.cli.main import main
from elastoplast.fem.discretize import nondimensionalize
from elastoplast.problem.definition import read_toml
from elastoplast.linalg.direct import FACTORIZATIONS, factorize_spd
from elastoplast.solvers.uzawa import UzawaOptions, load_sweep, metric_matrix, rho_bound, solve_uzawa
from elastoplast.solvers.contact import contact_operators, project_contact, solve_contact_qp

PROBLEMS = Path(__file__).resolve().parents[1] / "problems"

#: small variants of the shipped problems, all with a plastic zone under the contact
SMALL = {
    "cylinder_2d": [40, 20],
    "sphere_block_3d": [10, 10, 5],
    "sphere_quarter_3d": [5, 5, 5],
}
#: Uzawa runs two decades below the agreement targets, so its own error is not what is measured
TIGHT = 1e-8


def problem_data(name: str, divisions: list[int] | None = None) -> dict:
    data = read_toml(PROBLEMS / f"{name}.toml")
    if divisions is not None:
        data["mesh"]["divisions"] = list(divisions)
    return data


@lru_cache(maxsize=None)
def small(name: str, divisions: tuple[int, ...] | None = None) -> ep.Discretization:
    div = list(divisions) if divisions else SMALL.get(name)
    return ep.discretize(ep.problem_from_dict(problem_data(name, div), PROBLEMS))


@lru_cache(maxsize=None)
def reference(name: str) -> ep.Solution:
    return ep.solve(small(name), "conic")


@pytest.mark.parametrize("name", ["cylinder_2d", "punch_2d_gmsh", "sphere_block_3d", "sphere_quarter_3d"])
def test_agrees_with_conic_reference(name):
    disc = small(name)
    ref = reference(name)
    assert ref.converged, ref.message
    assert ref.plastic.any(), "the comparison must include a plastic zone"
    sol = ep.solve(disc, "uzawa", tol=TIGHT)
    assert sol.converged, sol.message
    assert sol.kkt.worst <= TIGHT  # the stopping test is the certificate's
    # issue 3: U to 1e-6 relative, stresses to 1e-5 in the energy norm, same sets
    assert_matches_reference(disc, sol, ref)


def test_iterations_do_not_grow_with_the_mesh():
    # docs/methods.md: the metric G makes the rate mesh independent; issue 3 asks
    # for counts within a factor 1.5 on three successively refined meshes. The
    # sequence starts where the plastic zone spans tens of elements (the 20 x 10
    # mesh has ten plastic elements, a different problem in all but name).
    counts = []
    for div in ([40, 20], [80, 40], [160, 80]):
        disc = small("cylinder_2d", tuple(div))
        sol = solve_uzawa(disc, UzawaOptions(tol=1e-6, check_every=1))
        assert sol.converged, sol.message
        assert sol.plastic.any()
        counts.append(sol.iterations)
    assert max(counts) <= 1.5 * min(counts), counts


@pytest.mark.parametrize("factor", [1.0, 1.5, -0.1, 0.0])
def test_rho_outside_the_bound_is_refused(factor):
    disc = small("sphere_quarter_3d")
    # docs/methods.md: convergence needs 0 < rho < 2 / lambda_max(C), lambda_max(C) = E / (1 - 2 nu)
    m = disc.material
    assert rho_bound(m) == pytest.approx(2 * (1 - 2 * m.nu) / m.E, rel=1e-14)
    with pytest.raises(ep.InputError) as err:
        ep.solve(disc, "uzawa", rho=factor * rho_bound(m))
    assert err.value.field == "rho"


def write_problem(tmp_path: Path, name: str, divisions: list[int]) -> Path:
    path = tmp_path / "problem.toml"
    data = problem_data(name, divisions)
    lines = []
    for section, table in data.items():
        lines.append(f"[{section}]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in table.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_cli_refuses_rho_above_the_bound(tmp_path, capsys):
    toml = write_problem(tmp_path, "cylinder_2d", [20, 10])
    # E = 2e5, nu = 0.3: the bound is 2 * 0.4 / 2e5 = 4e-6
    code = main(["solve", str(toml), "--method", "uzawa", "--rho", "4e-6", "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: rho:")


def test_cli_writes_history_and_convergence_plot(tmp_path):
    toml = write_problem(tmp_path, "cylinder_2d", [20, 10])
    out = tmp_path / "out"
    assert main(["solve", str(toml), "--method", "uzawa", "--tol", "1e-6", "--out", str(out), "--quiet"]) == 0
    data = json.loads((out / "summary.json").read_text())
    assert data["method"] == "uzawa" and data["status"] == "converged"
    assert data["kkt_worst"] <= 1e-6
    hist = data["history"]
    assert hist and set(hist[-1]) >= {"iteration", "residuals", "U", "n_active", "n_plastic", "time_s"}
    assert hist[-1]["U"] == pytest.approx(data["U"])
    assert (out / "convergence.png").stat().st_size > 0


def test_max_iterations_reports_status_and_true_residuals():
    disc = small("cylinder_2d")
    sol = solve_uzawa(disc, UzawaOptions(max_iter=5, check_every=1))
    assert sol.status is ep.Status.MAX_ITERATIONS
    assert sol.iterations == 5 and len(sol.history) == 6
    true = ep.certify(disc, sol.sigma, sol.xi, sol.u, sol.U)
    assert sol.kkt == true
    assert sol.kkt.worst > 1e-6  # five steps are far from the solution
    # the history's last row is the same certificate, evaluated in scaled units
    last = sol.history[-1]["residuals"]
    for key, value in true.as_dict().items():
        assert last[key] == pytest.approx(value, rel=1e-6, abs=1e-13)


def test_divergence_test_stops_the_run():
    """A worst residual above divergence_factor times the first one ends the run as
    diverged; a factor below 1 is refused (the first residual itself would count)."""
    from elastoplast.fem.discretize import nondimensionalize
    from elastoplast.solvers.loop import Monitor

    disc, ref = small("cylinder_2d"), reference("cylinder_2d")
    nd, units = nondimensionalize(disc)
    monitor = Monitor("uzawa", disc, nd, units, UzawaOptions(progress=False), divergence_factor=10.0)
    sigma, xi = ref.sigma / units.stress, ref.xi / units.stress
    u, U = disc.free_displacement(ref.u) / units.displacement, ref.U / units.displacement
    assert monitor.check(0, 2 * sigma, xi, u, U) is None  # the first residual sets the scale
    grown = monitor.check(1, 50 * sigma, xi, u, U)
    assert grown is not None and grown.status is ep.Status.DIVERGED, grown
    assert monitor.history[1]["kkt_worst"] > 10.0 * monitor.history[0]["kkt_worst"]
    with pytest.raises(ep.InputError) as exc:
        UzawaOptions(divergence_factor=1e-30)
    assert exc.value.field == "divergence_factor"


def test_options_of_other_methods_are_refused():
    """Issue 9: an option the method does not have is an error naming it, never ignored."""
    disc = small("sphere_quarter_3d")
    with pytest.raises(ep.InputError) as exc:
        ep.solve(disc, "uzawa", tol=1e-6, max_iter=2000, threads=3)
    assert exc.value.field == "threads"
    with pytest.raises(ep.InputError) as exc:
        ep.solve(disc, "newton", rho=1e-6)
    assert exc.value.field == "rho"


def test_warm_start_same_answer_fewer_iterations():
    disc = small("cylinder_2d")
    F = disc.force
    cold = solve_uzawa(disc, UzawaOptions(tol=TIGHT, check_every=1))
    previous = solve_uzawa(disc.with_force(0.9 * F), UzawaOptions(tol=TIGHT, check_every=1))
    warm = solve_uzawa(disc, UzawaOptions(tol=TIGHT, check_every=1, initial=previous))
    assert cold.converged and warm.converged
    assert warm.iterations < cold.iterations
    # Hencky's law is path independent: both are the unique solution, certified to TIGHT
    assert abs(warm.U - cold.U) <= 1e-6 * abs(cold.U)
    assert energy_error(disc, warm, cold) <= 1e-5
    np.testing.assert_array_equal(warm.plastic, cold.plastic)
    # load sweep: the last solve of the sweep is the same solution again
    sweep = load_sweep(disc, [0.9 * F, F], UzawaOptions(tol=TIGHT, check_every=1))
    assert sweep[1].iterations == warm.iterations
    assert abs(sweep[1].U - cold.U) <= 1e-6 * abs(cold.U)


def test_contact_qp_is_solved_exactly():
    rng = np.random.default_rng(3)
    n = 40
    M = rng.standard_normal((n, n))
    S = M @ M.T / n + np.eye(n) + 1.0
    g = rng.standard_normal(n)
    lam = solve_contact_qp(S, g)
    w = S @ lam + g
    # KKT conditions of min 1/2 lam S lam + g lam, lam >= 0, to rounding
    eps = 1e-12 * np.abs(g).max()
    assert lam.min() >= 0 and w.min() >= -eps and np.abs(lam * w).max() <= eps * np.abs(lam).max()
    assert 0 < np.count_nonzero(lam) < n  # both kinds of constraint occur
    # a warm start from another point reaches the same minimiser (it is unique: S is SPD)
    again = solve_contact_qp(S, g, lam0=rng.uniform(0, 1, n))
    np.testing.assert_allclose(again, lam, rtol=1e-10, atol=1e-12)


def test_contact_step_satisfies_its_optimality_conditions():
    nd, _ = nondimensionalize(small("cylinder_2d"))
    G = metric_matrix(nd)
    solve = factorize_spd(G)
    ops = contact_operators(nd.N, solve)
    rng = np.random.default_rng(0)
    u = np.zeros(nd.n_free)
    r = rng.standard_normal(nd.n_free)
    rho = 0.5
    v, V, lam = project_contact(u, 0.0, r, rho, nd.force, nd.N, nd.psi, solve, ops)
    # stationarity of 1/2|v-u|_G^2 + w/2 V^2 + rho r.v - rho F V - lam.(N v + psi - V)
    scale = np.linalg.norm(rho * r)
    assert np.linalg.norm(G @ (v - u) + rho * r - nd.N.T @ lam) <= 1e-10 * scale
    assert ops.weight * V == pytest.approx(rho * nd.force - lam.sum(), rel=1e-9)
    g = gaps(nd, v, V)
    assert lam.min() >= 0 and g.min() >= -1e-12 * np.abs(g).max()
    assert np.abs(lam * g).max() <= 1e-12 * np.abs(lam).max() * np.abs(g).max()


def test_factorizations_agree():
    disc = small("sphere_quarter_3d")
    G = metric_matrix(disc)
    b = np.random.default_rng(1).standard_normal(G.shape[0])
    for name, make in FACTORIZATIONS.items():
        try:
            solve = make(G)
        except ImportError:
            continue
        x = solve(b)
        assert np.linalg.norm(G @ x - b) <= 1e-10 * np.linalg.norm(b), name
        X = solve(np.column_stack([b, 2 * b]))
        np.testing.assert_allclose(X[:, 1], 2 * x, rtol=1e-10, atol=1e-14 * np.abs(x).max())


def test_weight_of_the_rigid_body_changes_speed_not_answer():
    # the weight w of V only changes the metric of step (ii); the fixed point is the
    # KKT point of (2.1) for every w > 0 (w = 1 is the paper's literal metric)
    disc = small("sphere_quarter_3d")
    auto = solve_uzawa(disc, UzawaOptions(tol=TIGHT))
    paper = solve_uzawa(disc, UzawaOptions(tol=TIGHT, rigid_weight=1.0))
    assert auto.converged and paper.converged
    assert abs(auto.U - paper.U) <= 1e-6 * abs(paper.U)
    assert energy_error(disc, auto, paper) <= 1e-5
    with pytest.raises(ep.InputError) as err:
        solve_uzawa(disc, UzawaOptions(rigid_weight=-1.0))
    assert err.value.field == "rigid_weight"
