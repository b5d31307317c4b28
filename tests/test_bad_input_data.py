"""Bad input, refusals that hold for the near-degenerate neighbourhood, not only
the exact case: a hardening next to zero, a mesh far from the origin, an inverted
bracket, obstacle keys the shape ignores, messages that blamed the wrong key, and the
Python API's argument checks. Each test names the exact input and asserts the exit code
or the InputError's field and message; thresholds are taken from their definitions."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp

import elastoplast as ep
from elastoplast.bounds.bracket import bracket_holds, combine
from elastoplast.references.certified import u_bracket_of
from elastoplast.bounds.equilibrium.bound import solve_lower_bound
from elastoplast.linalg.direct import project_affine
from elastoplast.bounds.bracket import GAP_FLOOR
from elastoplast.references.solves import best_upper_bound
from elastoplast.certificate.solution import Status, largest_strain, make_solution
from elastoplast.cli.main import main
from elastoplast.errors import InputError
from elastoplast.fem.discretize import MIN_HARDENING_OVER_E
from elastoplast.fem.locking import BEARING_FACTOR, SMALL_STRAIN_LIMIT, check_hardening_carries_load
from elastoplast.mesh.base import ROUND_OFF_SHARE, shortest_edge, write_mesh
from elastoplast.problem.definition import MAX_PSI_OVER_SPAN
from elastoplast.solvers.registry import check_solvable

from conftest import PROBLEMS, ROOT, build
from test_cli import small_cylinder, write_toml

DEFAULT = ROOT / "elastoplast" / "data" / "default.toml"  # the built-in default problem
SIGMA_Y = 250.0
PRANDTL = (2.0 + math.pi) * SIGMA_Y / math.sqrt(3.0)  # the half model's limit load, half-width 1


def cli(capsys, *argv) -> tuple[int, str]:
    """Exit code and the last line on stderr."""
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err[-1] if err else ""


def quietly(make):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return make()


def refused(make) -> InputError:
    with pytest.raises(InputError) as exc:
        quietly(make)
    return exc.value


def half_punch(pattern: str, hardening: float, force: float, divisions=(10, 5)) -> dict:
    """A flat punch of half-width 1 on a half model (tests/test_commands.py's)."""
    return {"mesh": {"generator": "rectangle", "size": [10.0, 5.0], "divisions": list(divisions), "grading": 1.5,
                     "contact_radius": 1.0, "pattern": pattern, "origin": [0.0, 0.0], "contact_center": [0.0]},
            "material": {"E": 200000.0, "nu": 0.3, "yield_stress": SIGMA_Y, "hardening": hardening},
            "boundary": {"clamped": ["xmax", "top"], "contact": ["contact"], "fix_component": {"x": ["xmin"]}},
            "obstacle": {"shape": "flat"}, "load": {"force": force}}


def bearing_ratio(disc) -> float:
    """The mean pressure over the contact zone in flow stresses sigma_y + SMALL_STRAIN_LIMIT H."""
    m = disc.material
    return disc.force / disc.contact_area.sum() / (m.yield_stress + SMALL_STRAIN_LIMIT * m.hardening)


# ---------------------------------------------------------------------------
# 1. a hardening next to zero
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("divisions", [None, [6, 6, 3]], ids=["default-mesh", "6x6x3"])
def test_tiny_hardening_on_tetrahedra_is_refused_like_zero(tmp_path, capsys, divisions):
    """default.toml with hardening = 1e-6 and force = 1e9 'converged' to U = 7654 on a 12 mm
    block (6x6x3 with force = 1e6: U = 2.7); H = 0 was refused there."""
    data = ep.read_toml(DEFAULT)
    data["material"]["hardening"] = 1e-6
    data["load"]["force"] = 1e9 if divisions is None else 1e6
    if divisions is not None:
        data["mesh"]["divisions"] = divisions
    code, line = cli(capsys, "solve", write_toml(tmp_path / "p.toml", data), "--out", tmp_path / "o", "--quiet")
    assert code == 2 and line.startswith("error: material.hardening:")
    assert "cannot carry" in line and "within small strains" in line and "tetrahedra" in line
    disc = quietly(lambda: build(data))
    assert bearing_ratio(disc) > BEARING_FACTOR  # the rule, from its definition


def test_numerically_zero_hardening_is_refused(tmp_path, capsys):
    """cylinder_2d with hardening = 1e-300 and force = 1e8 'converged' to U = 7257."""
    data = small_cylinder()
    data["mesh"]["divisions"] = [16, 8]
    data["material"]["hardening"] = 1e-300
    data["load"]["force"] = 1e8
    assert 0 < 1e-300 < MIN_HARDENING_OVER_E * data["material"]["E"]
    code, line = cli(capsys, "solve", write_toml(tmp_path / "p.toml", data), "--out", tmp_path / "o", "--quiet")
    assert code == 2 and line.startswith("error: material.hardening:")
    assert "numerically zero" in line and "use 0 for perfect plasticity" in line


def test_the_locking_estimate_refuses_from_its_threshold_on():
    """The estimate at its threshold: the 6x6x3 default block, H = 1e-6, with the force
    just below and just above BEARING_FACTOR flow stresses over the contact zone."""
    data = ep.read_toml(DEFAULT)
    data["mesh"]["divisions"] = [6, 6, 3]
    data["material"]["hardening"] = 1e-6
    disc = quietly(lambda: build(data))
    m = disc.material
    limit = BEARING_FACTOR * (m.yield_stress + SMALL_STRAIN_LIMIT * m.hardening) * disc.contact_area.sum()
    check_hardening_carries_load(disc.with_force(0.999 * limit))
    with pytest.raises(InputError) as exc:
        check_hardening_carries_load(disc.with_force(1.001 * limit))
    assert exc.value.field == "material.hardening"
    # a mesh that does not lock is left to the strain of its answer
    crossed = quietly(lambda: build(half_punch("crossed", 1e-6, 1.0)))
    force = 2 * BEARING_FACTOR * SIGMA_Y * crossed.contact_area.sum()
    check_hardening_carries_load(crossed.with_force(force))


def test_shipped_problems_pass_the_locking_estimate_with_room():
    for path in sorted(PROBLEMS.glob("*.toml")) + [DEFAULT]:
        data = ep.read_toml(path)
        if "campaign" in data:
            continue
        disc = quietly(lambda: build(data))
        check_solvable(disc, "conic")
        assert bearing_ratio(disc) < BEARING_FACTOR / 10, path.name


@pytest.mark.parametrize("method", ["conic", "conic-cvxpy", "conic-displacement", "newton", "uzawa-fast", "uzawa"])
def test_an_answer_beyond_small_strains_is_not_converged(method):
    """A crossed (non-locking) punch with H = 20 at 1.2 times Prandtl's load: the answer
    certifies (KKT at round-off) but its strain leaves the small-strain model."""
    disc = quietly(lambda: build(half_punch("crossed", 20.0, 1.2 * PRANDTL)))
    sol = ep.solve(disc, method)
    assert sol.status is not Status.CONVERGED
    strain, _ = largest_strain(disc, disc.free_displacement(sol.u))
    if method != "uzawa":  # uzawa stops at max_iter on this problem first
        assert sol.status is Status.FAILED and strain > SMALL_STRAIN_LIMIT
        assert sol.message.count("leaves the small-strain model") == 1 and f"above {SMALL_STRAIN_LIMIT:g}" in sol.message
    # the loops' way in: make_solution never calls it converged either
    again = make_solution(disc, method=method, status=Status.CONVERGED, sigma=sol.sigma, xi=sol.xi,
                          u_free=disc.free_displacement(sol.u), U=sol.U, iterations=1, timings={})
    assert again.status is Status.FAILED if strain > SMALL_STRAIN_LIMIT else again.status is Status.CONVERGED


def test_the_small_strain_verdict_exits_1_and_spares_the_limit_load_below(tmp_path, capsys):
    code, line = cli(capsys, "solve", write_toml(tmp_path / "p.toml", half_punch("crossed", 20.0, 1.2 * PRANDTL)),
                     "--out", tmp_path / "o", "--quiet")
    assert code == 1 and "small-strain model" in line
    below = quietly(lambda: build(half_punch("crossed", 20.0, 0.9 * PRANDTL)))
    sol = ep.solve(below, "conic")
    assert sol.converged and largest_strain(below, below.free_displacement(sol.u))[0] < SMALL_STRAIN_LIMIT


# ---------------------------------------------------------------------------
# 2. a mesh file far from the origin
# ---------------------------------------------------------------------------


def shifted_rectangle(path, shift: float):
    mesh = ep.structured_mesh([40.0, 20.0], [20, 10], 4.0)
    write_mesh(path, ep.Mesh(mesh.points + [shift, 0.0], mesh.cells, mesh.groups))
    return path, mesh


def file_problem(path, shift: float) -> dict:
    return {"mesh": {"file": str(path)}, "material": {"E": 200000.0, "nu": 0.3, "yield_stress": 1200.0,
                                                      "hardening": 10000.0},
            "boundary": {"clamped": ["xmin", "xmax", "top"], "contact": ["contact"]},
            "obstacle": {"shape": "cylinder", "radius": 40.0, "center": [shift]}, "load": {"force": 4315.0}}


def test_mesh_file_far_from_the_origin_is_refused(tmp_path, capsys):
    """The 20x10 rectangle on 40x20 shifted by 1e14 gave U = 0.0430613 (0.0430797 at the
    origin), called converged; the generator's origin = [1e14, 0] was already refused."""
    path, _ = shifted_rectangle(tmp_path / "far.msh", 1e14)
    code, line = cli(capsys, "solve", write_toml(tmp_path / "p.toml", file_problem(path, 1e14)),
                     "--out", tmp_path / "o", "--quiet")
    assert code == 2 and line.startswith("error: mesh.file:")
    assert "round-off" in line and "1e+14" in line and "translate the mesh" in line
    near, _ = shifted_rectangle(tmp_path / "near.msh", 0.0)
    assert cli(capsys, "solve", write_toml(tmp_path / "q.toml", file_problem(near, 0.0)),
               "--out", tmp_path / "o2", "--quiet")[0] == 0
    data = small_cylinder()
    data["mesh"]["origin"] = [1e14, 0.0]
    exc = refused(lambda: ep.problem_from_dict(data))
    assert exc.field == "mesh.origin" and "round-off" in exc.message  # the same rule


def test_far_mesh_threshold_is_the_generators(tmp_path):
    """One rule for both paths: the shortest edge against ROUND_OFF_SHARE of the largest coordinate."""
    _, mesh = shifted_rectangle(tmp_path / "m.msh", 0.0)
    edge = shortest_edge(mesh.points, mesh.cells)
    path, _ = shifted_rectangle(tmp_path / "ok.msh", 0.5 * edge / ROUND_OFF_SHARE)  # about the largest coordinate
    assert quietly(lambda: ep.read_mesh(path)).n_elements == mesh.n_elements
    path, _ = shifted_rectangle(tmp_path / "far.msh", 2 * edge / ROUND_OFF_SHARE)
    assert refused(lambda: ep.read_mesh(path)).field == "mesh.file"


# ---------------------------------------------------------------------------
# 3. the bracket: never inverted and certified, no raw floating-point warnings
# ---------------------------------------------------------------------------


def test_bounds_with_numerically_zero_hardening_is_refused(tmp_path, capsys):
    """problems/cylinder_2d.toml, divisions [16, 8], hardening 1e-300 wrote energy in
    [-0, -86.69], U in [2159.88, -2159.88], 'stress error <= 0', with overflow warnings."""
    data = ep.read_toml(PROBLEMS / "cylinder_2d.toml")
    data["mesh"]["divisions"] = [16, 8]
    data["material"]["hardening"] = 1e-300
    code, line = cli(capsys, "bounds", write_toml(tmp_path / "p.toml", data), "--out", tmp_path / "b", "--quiet")
    assert code == 2 and line.startswith("error: material.hardening:") and "numerically zero" in line


def test_an_inverted_bracket_is_never_certified():
    data = ep.read_toml(PROBLEMS / "cylinder_2d.toml")
    data["mesh"]["divisions"] = [16, 8]
    disc = build(data)
    sol = ep.solve(disc, "conic")
    upper, lower = best_upper_bound(disc, sol), solve_lower_bound(disc)
    good = combine(upper, lower)
    assert good.bounds_certified and good.energy_lower <= good.energy_upper
    inverted = replace(upper, Pi=good.energy_lower - 0.1 * abs(good.energy_lower))  # both sides still "certified"
    with pytest.warns(UserWarning, match="inverted"):
        b = combine(inverted, lower)
    assert not b.bounds_certified and math.isnan(b.stress_error_bound)  # no clamp to 0
    # the U bracket from an inverted energy bracket: U_lower > U_upper, not certified
    with pytest.warns(UserWarning, match="inverted"):
        U_lo, U_hi, _, certified = u_bracket_of(disc, replace(good, energy_upper=good.energy_lower - 1e3), sol.U)
    assert U_lo > U_hi and not certified
    # round-off: within GAP_FLOOR of the energies the order holds, beyond it not
    hi = good.energy_upper
    assert bracket_holds(hi + 0.5 * GAP_FLOOR * abs(hi), hi)
    assert not bracket_holds(hi + 2.0 * GAP_FLOOR * abs(hi), hi)
    assert not bracket_holds(math.nan, hi) and not bracket_holds(-math.inf, hi)


def test_overflow_in_the_repair_is_no_raw_warning():
    A = sp.identity(2, format="csc")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a RuntimeWarning would raise
        _, residual = project_affine(A, np.array([1e308, 1e308]), np.array([-1e308, -1e308]))
    assert residual == math.inf


# ---------------------------------------------------------------------------
# 4. keys the obstacle's shape does not use
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("obstacle,field,words", [
    ({"shape": "cylinder", "radius": 40.0, "expression": "0.01*x**2"}, "obstacle.expression",
     'only for shape = "expression", not for shape = "cylinder"'),
    ({"shape": "flat", "radius": 40.0}, "obstacle.radius", 'not for shape = "flat"'),
    ({"shape": "expression", "expression": "0.01*x**2", "radius": 40.0}, "obstacle.radius",
     'not for shape = "expression"'),
])
def test_obstacle_keys_the_shape_ignores_are_refused(obstacle, field, words):
    data = small_cylinder()
    data["obstacle"] = obstacle
    exc = refused(lambda: ep.problem_from_dict(data))
    assert exc.field == field and words in exc.message


# ---------------------------------------------------------------------------
# 5. messages that named the wrong culprit
# ---------------------------------------------------------------------------


def contact_span(data: dict) -> float:
    mesh = quietly(lambda: ep.problem_from_dict(data)).mesh
    x = mesh.points[mesh.group_nodes(["contact"]), 0]
    return float(x.max() - x.min())


def test_a_far_obstacle_is_not_called_steep():
    data = small_cylinder()
    span = contact_span(data)
    data["obstacle"] = {"shape": "expression", "expression": "1e8 + 0.01*x**2"}  # the input
    assert 1e8 > MAX_PSI_OVER_SPAN * span
    exc = refused(lambda: ep.discretize(ep.problem_from_dict(data)))
    assert exc.field == "obstacle.expression" and "lies 1e+08 below the contact zone" in exc.message
    assert "steep" not in exc.message
    # a gap within the bound is a warning, as before
    data["obstacle"]["expression"] = f"{0.5 * MAX_PSI_OVER_SPAN * span!r} + 0.01*x**2"
    with pytest.warns(UserWarning, match="does not touch the body before loading"):
        ep.discretize(ep.problem_from_dict(data))
    # the relief, not the height, makes a surface steep
    data["obstacle"]["expression"] = "1e8*x**2"
    exc = refused(lambda: ep.discretize(ep.problem_from_dict(data)))
    assert exc.field == "obstacle.expression" and "steep" in exc.message


def test_a_body_group_named_as_contact_says_what_it_is():
    data = ep.read_toml(PROBLEMS / "punch_2d_gmsh.toml")
    data["boundary"]["contact"] = ["body"]
    exc = refused(lambda: ep.problem_from_dict(data, base_dir=PROBLEMS))
    assert exc.field == "boundary.contact"
    assert "'body' is a 2-dimensional physical group; boundary groups must be facets (lines in 2D)" in exc.message


@pytest.mark.parametrize("boundary,field", [
    ({"clamped": ["xmin", "xmax", "top", "contact"]}, "boundary.clamped"),
    ({"clamped": ["xmin", "xmax", "top"], "fix_component": {"y": ["contact"]}}, "boundary.fix_component.y"),
    ({"clamped": ["xmin", "xmax", "top", "bottom"]}, "boundary.clamped"),
])
def test_a_fixed_contact_group_names_the_boundary_list(boundary, field):
    data = small_cylinder()
    data["boundary"] = boundary
    exc = refused(lambda: ep.problem_from_dict(data))
    assert exc.field == field and "contact zone" in exc.message


def test_nearly_incompressible_warning_keeps_the_digits():
    data = small_cylinder()
    data["material"]["nu"] = 0.4999999
    with pytest.warns(UserWarning, match=r"material\.nu = 0\.4999999 is nearly incompressible"):
        ep.problem_from_dict(data)


# ---------------------------------------------------------------------------
# 6. the Python API's arguments
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("args,kwargs,field", [
    (([8.0, 4.0], [8, 4], 1.0), {"pattern": "foo"}, "mesh.pattern"),
    (([8.0, 4.0], [8, 4], 1.0), {"grading": 0.5}, "mesh.grading"),
    (([8.0, 4.0], [8, 4], -1.0), {}, "mesh.contact_radius"),
    (([8.0, 4.0], [8, 4], math.inf), {}, "mesh.contact_radius"),
    (([8.0, 4.0], [8, 4], 1.0), {"origin": [0, 5]}, "mesh.origin"),
    (([8.0, 4.0], [8, 4], 1.0), {"origin": [0, 0, 0]}, "mesh.origin"),
    (([8.0, 4.0], [8, 4], 1.0), {"contact_center": [100]}, "mesh.contact_center"),
    (([8.0, 4.0], [4.5, 2], 1.0), {}, "mesh.divisions"),
    (([8.0, 4.0], [4, "2"], 1.0), {}, "mesh.divisions"),
    (([8.0, 4.0], None, 1.0), {}, "mesh.divisions"),
    (([8.0, 4.0], [4], 1.0), {}, "mesh.divisions"),
    (("8x4", [8, 4], 1.0), {}, "mesh.size"),
    ((None, [8, 4], 1.0), {}, "mesh.size"),
    (([8.0], [8], 1.0), {}, "mesh.size"),
    (([8.0, -4.0], [8, 4], 1.0), {}, "mesh.size"),
])
def test_structured_mesh_checks_its_arguments(args, kwargs, field):
    exc = refused(lambda: ep.structured_mesh(*args, **kwargs))
    assert exc.field == field


@pytest.mark.parametrize("args,field", [
    (("2e5", 0.3, 250.0, 1.0), "material.E"),
    ((None, 0.3, 250.0, 1.0), "material.E"),
    (([1], 0.3, 250.0, 1.0), "material.E"),
    ((math.inf, 0.3, 250.0, 1.0), "material.E"),
    ((True, 0.3, 250.0, 1.0), "material.E"),
    ((2e5, 0.3, 250.0, True), "material.hardening"),
    ((2e5, "0.3", 250.0, 1.0), "material.nu"),
])
def test_make_material_takes_finite_numbers_only(args, field):
    exc = refused(lambda: ep.make_material(*args))
    assert exc.field == field and "finite number" in exc.message


def test_problem_from_dict_without_a_base_dir():
    data = small_cylinder()
    assert quietly(lambda: ep.problem_from_dict(data, base_dir=None)).dim == 2
    assert refused(lambda: ep.problem_from_dict(data, base_dir=3)).field == "base_dir"


def test_contact_radius_of_an_obstacle_centred_outside_the_zone(tmp_path):
    """Found in the third pass: a cylinder of radius 4000 centred at x = 3000, beside a
    40 mm block, touches near the zone's edge; the contact radius was measured from
    the far centre (2998 for a zone 8 mm wide). It is now the half-extent of the
    active set, so never more than half the contact zone's width."""
    data = small_cylinder()
    data["obstacle"] = {"shape": "cylinder", "radius": 4000.0, "center": [3000.0]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the obstacle does not touch before loading: said in a warning
        disc = build(data)
    sol = ep.solve(disc, "conic")
    xp = disc.mesh.points[disc.contact_nodes, 0]
    assert sol.converged and np.any(sol.active)
    width = float(np.ptp(xp))
    radius = ep.summary(disc, sol)["contact_radius"]
    assert 0.0 <= radius <= 0.5 * width
    assert radius == pytest.approx(0.5 * float(np.ptp(xp[sol.active])))
