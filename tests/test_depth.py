"""Depth control (issue 36): the rigid body's displacement U = delta prescribed, F found.

Origins of the figures: the round trip is the identity F(U(F0)) = F0 (the same convex
problem, V fixed at the value the force-controlled solve found); proportionality is the
positive homogeneity of linear elasticity under a flat punch (psi = 0: with (u, lam) a
solution at delta, (2u, 2lam) is one at 2 delta); lift-off is the unloaded state, which
satisfies every condition when delta is at or below the smallest gap; the depth path
repeats the force path's steps (the same backward-Euler step problems).
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.solvers.depth import DEPTH_TOL, FLOOR_SHARE

from conftest import cylinder_dict

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "plugin_method"
F0 = 4315.0


@pytest.fixture(scope="module")
def data():
    return cylinder_dict((20, 10))


@pytest.fixture(scope="module")
def disc(data):
    return ep.discretize(ep.problem_from_dict(data))


@pytest.fixture(scope="module")
def reference(disc):
    return ep.solve(disc, "conic")


def depth_dict(data, **load):
    out = copy.deepcopy(data)
    out["load"] = load
    return out


# each method's U at F0 agrees with conic's to about its tol (1e-6 relative, tests/test_uzawa.py and
# test_newton.py); F(U) has a log-slope below 2 here, so F agrees to a few times that
@pytest.mark.parametrize("method, values, rtol", [
    ("conic", {}, 1e-6),
    ("conic-cvxpy", {}, 1e-5),
    ("conic-displacement", {}, 1e-5),
    ("newton", {"linear_solver": "splu"}, 1e-5),
    ("newton", {"linear_solver": "amg"}, 1e-5),
    ("uzawa", {}, 1e-4),
    ("uzawa-fast", {}, 1e-4),
    ("uzawa-fast", {"variant": "alg2"}, 1e-4),
])
def test_round_trip_every_method(data, reference, method, values, rtol):
    problem = ep.problem_from_dict(depth_dict(data, displacement=reference.U))
    assert problem.depth_controlled and problem.displacement == reference.U
    disc = ep.discretize(problem)
    out = ep.solve_depth(disc, problem.displacement, method, **values)
    assert out.converged and not out.lift_off, out.solution.message
    assert out.residual <= DEPTH_TOL
    assert abs(out.force - F0) <= rtol * F0, (out.force, out.forces)
    # F is the multiplier of the fixed U: the contact forces sum to it
    assert abs(out.summary()["contact_force_sum"] - out.force) <= rtol * F0


def test_round_trip_plugin(monkeypatch):
    monkeypatch.syspath_prepend(str(EXAMPLE))
    disc = ep.discretize(ep.load_problem(EXAMPLE / "small_2d.toml"))
    ref = ep.solve(disc, "newton")
    out = ep.solve_depth(disc, ref.U, "jacobi_uzawa:METHOD", force_guess=0.5 * disc.force)
    assert out.converged
    # the plug-in's U agrees with newton's to 1e-5 (tests/test_plugins.py)
    assert abs(out.force - disc.force) <= 1e-4 * disc.force


def test_linear_elasticity_force_proportional_to_depth(data):
    elastic = depth_dict(data, displacement=0.01)
    elastic["obstacle"] = {"shape": "flat"}
    elastic["material"].update(yield_stress=1e12)
    disc = ep.discretize(ep.problem_from_dict(elastic))
    one = ep.solve_depth(disc, 0.01, "conic")
    two = ep.solve_depth(disc, 0.02, "conic")
    assert not one.solution.plastic.any() and not two.solution.plastic.any()
    assert abs(two.force - 2.0 * one.force) <= 1e-6 * two.force
    # and back through force control: U(F(delta)) = delta
    assert abs(ep.solve(disc.with_force(one.force), "conic").U - 0.01) <= 1e-6 * 0.01


@pytest.mark.parametrize("delta", [-0.01, 0.0])
def test_lift_off_gives_zero_force(data, delta):
    problem = ep.problem_from_dict(depth_dict(data, displacement=delta))
    disc = ep.discretize(problem)
    assert np.min(disc.psi) == 0.0  # the cylinder touches at its centre
    out = ep.solve_depth(disc, delta, "newton")
    assert out.lift_off and out.force == 0.0 and out.solution is None and out.residual == 0.0
    summary = out.summary()
    assert summary["force"] == 0.0 and summary["contact_force_sum"] == 0.0 and summary["U"] == delta


def test_depth_path_agrees_with_force_path_and_unloads_to_zero(disc):
    forces = [2000.0, F0, 2000.0, 100.0]
    by_force = ep.solve_path(disc, forces, "conic")
    assert by_force.converged
    by_depth, searches = ep.solve_depth_path(disc, list(by_force.U) + [0.0], "conic")
    assert by_depth.control == "displacement" and by_depth.converged
    found = [s.force for s in by_depth.steps]
    np.testing.assert_allclose(found[:4], forces, rtol=1e-6)
    # unloading by depth to U = 0: the body springs back short of it (plastic strain, a residual imprint),
    # contact is lost and the last step is solved at 1e-6 of the largest force
    last = searches[-1]
    floor = FLOOR_SHARE * max(found)
    assert last.lift_off and last.force == pytest.approx(floor)
    imprint = by_depth.steps[-1].U
    assert 0.0 < imprint < by_force.U[-1]
    # the same step by force gives the same imprint (the same step problem)
    again = ep.solve_path(disc, forces + [floor], "conic")
    assert abs(again.U[-1] - imprint) <= 1e-6 * by_force.U[1]


@pytest.mark.parametrize("load, field", [
    ({"force": 10.0, "displacement": 0.01}, "load"),
    ({"path": [1.0], "displacement_path": [0.01]}, "load"),
    ({"displacement": "deep"}, "load.displacement"),
    ({"displacement": True}, "load.displacement"),
    ({"displacement": float("nan")}, "load.displacement"),
    ({"displacement_path": []}, "load.displacement_path"),
    ({"displacement_path": [0.01, "x"]}, "load.displacement_path"),
    ({"force": -1.0}, "load.force"),
])
def test_bad_input_names_the_field(data, load, field):
    with pytest.raises(ep.InputError) as info:
        ep.problem_from_dict(depth_dict(data, **load))
    assert info.value.field == field


def test_force_solvers_refuse_a_depth_problem(data):
    disc = ep.discretize(ep.problem_from_dict(depth_dict(data, displacement=0.02)))
    for call in (lambda: ep.solve(disc), lambda: ep.solve_path(disc, [1.0])):
        with pytest.raises(ep.InputError) as info:
            call()
        assert info.value.field == "load.displacement"
    with pytest.raises(ep.InputError, match="^depth_tol"):
        ep.solve_depth(disc, 0.02, depth_tol=2.0)


def test_axisymmetric_sphere_round_trip_and_lift_off():
    """The meridian-plane sphere (problems/sphere_axisymmetric.toml, coarser): depth control
    gives back the force whose U it prescribes (the whole force on the indenter)."""
    data = ep.read_toml(Path(__file__).resolve().parents[1] / "problems" / "sphere_axisymmetric.toml")
    data["mesh"]["divisions"] = [20, 20]
    disc = ep.discretize(ep.problem_from_dict(data))
    force = ep.solve(disc, "conic")
    depth = ep.problem_from_dict(depth_dict(data, displacement=force.U))
    assert depth.axisymmetric and depth.depth_controlled
    out = ep.solve_depth(ep.discretize(depth), force.U, "newton")
    assert out.converged and abs(out.force - data["load"]["force"]) <= 1e-5 * data["load"]["force"]
    assert ep.solve_depth(ep.discretize(depth), -1e-3, "newton").force == 0.0


def test_command_line_depth_control(data, tmp_path, capsys):
    import json

    from elastoplast.cli.main import main

    for name, load in (("d", "displacement = 0.03"), ("l", "displacement = -0.01"),
                       ("p", "displacement_path = [0.02, 0.04, 0.0]")):
        text = (Path(__file__).resolve().parents[1] / "problems" / "cylinder_2d.toml").read_text()
        text = text.replace("force = 4315.0", load).replace("divisions = [80, 40]", "divisions = [20, 10]")
        (tmp_path / f"{name}.toml").write_text(text)
        assert main(["solve", str(tmp_path / f"{name}.toml"), "--out", str(tmp_path / name), "--quiet"]) == 0
    found = json.loads((tmp_path / "d" / "summary.json").read_text())
    assert found["control"] == "displacement" and found["displacement"] == 0.03
    assert abs(found["U"] - 0.03) <= DEPTH_TOL * 0.03 and found["lift_off"] is False
    # the summary's force is the one found, and the contact forces carry it
    assert abs(found["contact_force_sum"] - found["force"]) <= 1e-6 * found["force"]
    lifted = json.loads((tmp_path / "l" / "summary.json").read_text())
    assert lifted["lift_off"] is True and lifted["force"] == 0.0
    path = json.loads((tmp_path / "p" / "summary.json").read_text())
    assert path["control"] == "displacement" and path["displacements"] == [0.02, 0.04, 0.0]
    assert path["forces"][1] == max(path["forces"]) and path["residual_imprint"]["U"] > 0.0
    for argv in (["bounds"], ["check", str(tmp_path / "d")]):  # check is refused before its answer is read
        assert main([argv[0], str(tmp_path / "d.toml"), *argv[1:]]) == 2
        assert "load.displacement" in capsys.readouterr().err
