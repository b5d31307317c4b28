"""Hostile inputs, issue 39's fourth pass of our own: one test per class found.

Warnings of Dask workers said like the command's own; the active set's relative
threshold in every step of a path; ``limit`` refusing what it cannot use and spending
one budget; loads no solver can scale refused wherever they enter (``with_force``, a
path's entries, a depth's first guess) naming what the user gave; a depth path's
lift-off search at a force its tolerance can certify; arrays in another layout refused,
not reshaped; slopes read off an unloading only where U resolves them.
"""

from __future__ import annotations

import json
import textwrap
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.certificate.kkt import ROUND_OFF
from elastoplast.certificate.solution import ACTIVE_FORCE_SHARE, make_solution, summary
from elastoplast.cli.main import main
from elastoplast.io.loading_path import path_oliver_pharr, step_entry, unloading_slope
from elastoplast.solvers.depth import floor_share

from test_cli import write_toml

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "examples" / "plugin_method" / "small_2d.toml"


def small_data(**load) -> dict:
    """small_2d.toml (144 triangles) without its plug-in [solver], with ``load`` as [load]."""
    data = ep.read_toml(SMALL)
    data.pop("solver", None)
    if load:
        data["load"] = load
    return data


def axisymmetric_data(**load) -> dict:
    """problems/sphere_axisymmetric.toml on an 8 x 8 grid (128 triangles)."""
    data = ep.read_toml(ROOT / "problems" / "sphere_axisymmetric.toml")
    data["mesh"]["divisions"] = [8, 8]
    if load:
        data["load"] = load
    return data


@pytest.fixture(scope="module")
def disc():
    return ep.discretize(ep.problem_from_dict(small_data()))


def error_lines(err: str) -> list[str]:
    return [line for line in err.strip().splitlines() if line.startswith("error:")]


def test_a_grazing_node_is_free_in_a_solve_and_in_every_path_step(disc, tmp_path):
    """A node carrying 4e-9 N beside a peak of 109 N (the ratio found against an
    independent code, 3.7e-11) is below ACTIVE_FORCE_SHARE = 1e-4 of the peak: the
    count and the contact radius of summary.json are those without it, in a plain
    solve and in a path step's entry; docs/outputs.md states the threshold."""
    sol = ep.solve(disc, "newton")
    r = disc.contact_radii()
    free = np.flatnonzero(~sol.active & (r > r[sol.active].max()))
    assert free.size, "small_2d has free contact nodes beyond the contact"
    lam = sol.contact_force.copy()
    lam[free[0]] = lam.max() * 4e-9 / 109.0
    assert lam[free[0]] > 0 and lam[free[0]] < ACTIVE_FORCE_SHARE * lam.max()
    grazed = make_solution(disc, method="newton", status=sol.status, sigma=sol.sigma, xi=sol.xi,
                           u_free=disc.free_displacement(sol.u), U=sol.U, contact_force=lam, iterations=1,
                           timings={})
    plain, touched = summary(disc, sol), summary(disc, grazed)
    assert touched["n_active_contact_nodes"] == plain["n_active_contact_nodes"]
    assert touched["contact_radius"] == plain["contact_radius"]
    path = ep.solve_path(disc, [disc.force], "newton")
    step = path.steps[0]
    entry = step_entry(disc, replace(step, solution=grazed))
    assert entry["n_active_contact_nodes"] == step_entry(disc, step)["n_active_contact_nodes"] == int(sol.active.sum())
    assert entry["contact_radius"] == pytest.approx(plain["contact_radius"], rel=1e-9)
    assert "1e-4 of the largest contact force" in (ROOT / "docs" / "outputs.md").read_text().replace("\n", " ")


def test_numpy_warnings_of_campaign_and_compare_workers_are_said_once(tmp_path, monkeypatch, capfd):
    """A plug-in answering 1e200 times the true field overflows in the certificate's
    arithmetic inside a Dask worker process, which printed numpy's raw warning (file,
    line and source) on the terminal; now each kind is one marked line of the command,
    in campaign and in compare, whose report prints n/a for the NaN figures."""
    (tmp_path / "ep_huge_w.py").write_text(textwrap.dedent("""
        import elastoplast as ep

        def run(disc, options):
            sol = ep.solve(disc, "newton")
            return 1e200 * sol.u, 1e200 * sol.U
    """))
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path) + ":" + str(ROOT))  # the worker processes import the plug-in
    data = small_data()
    data["mesh"]["divisions"] = [8, 4]
    data["campaign"] = {"name": "w"}
    data["sweep"] = {"method": ["newton", "ep_huge_w:run"]}
    campaign = write_toml(tmp_path / "c.toml", data)
    store = tmp_path / "store"
    assert main(["campaign", str(campaign), "--out", str(store), "--workers", "1", "--quiet"]) == 1
    err = capfd.readouterr().err
    assert "RuntimeWarning" not in err and "encountered in" in err, err
    said = [line for line in err.splitlines() if "encountered in" in line]
    assert len(said) == len(set(said)) and all(s.startswith("warning: floating-point arithmetic: ") for s in said)
    assert main(["compare", str(store), "--method", "ep_huge_w:run", "--reference-method", "newton", "--workers", "1",
                 "--quiet"]) == 1
    err = capfd.readouterr().err
    assert "RuntimeWarning" not in err and "warning: floating-point arithmetic: " in err, err
    report = (store / "compare-ep_huge_w:run" / "report.md").read_text()
    assert "n/a" in report and "nan" not in report


def test_help_says_what_each_time_limit_bounds(capsys):
    """solve: the whole run; adapt: its budget; compare: each case's solve; campaign (no
    flag): the file's solver.time_limit, per case; limit: the whole bracket."""
    said = {}
    for command in ("solve", "adapt", "campaign", "compare", "limit"):
        assert main([command, "--help"]) == 0
        said[command] = " ".join(capsys.readouterr().out.split())
    assert "of the whole run" in said["solve"]
    assert "time budget" in said["adapt"]
    assert "each case's solve" in said["compare"]
    assert "time_limit" in said["campaign"] and "each case's solve" in said["campaign"]
    assert "the whole bracket" in said["limit"]


def test_limit_refuses_a_path_notes_solver_and_spends_one_budget(tmp_path, capsys, monkeypatch):
    """A path is refused naming load.path (it was 'disc' with Python advice); a [solver]
    table, which limit does not use, is noted; the static program gets what the
    kinematic one left of --time-limit (stubbed: the kinematic program takes 0.3 s)."""
    import elastoplast.bounds.limit_load as limit_load

    data = small_data(path=[1000.0, 2000.0])
    data["material"]["hardening"] = 0.0
    data["mesh"].update(pattern="crossed", divisions=[8, 4])
    out = str(tmp_path / "out")
    assert main(["limit", str(write_toml(tmp_path / "p.toml", data)), "--out", out, "--quiet"]) == 2
    lines = error_lines(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith("error: load.path: 'limit' takes Hencky's problem")
    data["load"] = {"force": 1000.0}
    data["solver"] = {"method": "newton"}
    assert main(["limit", str(write_toml(tmp_path / "q.toml", data)), "--out", out, "--quiet"]) in (0, 1)
    assert "note: solver: the limit load's two programs are Clarabel's" in capsys.readouterr().err
    seen = {}

    def static(disc, lower_options):
        seen["time_limit"] = lower_options.time_limit
        raise RuntimeError("the static program is not run here")

    monkeypatch.setattr(limit_load, "kinematic_limit_load", lambda disc, options: time.sleep(0.3))
    monkeypatch.setattr(limit_load, "static_limit_load", static)
    with pytest.raises(RuntimeError):
        limit_load.limit_load(ep.discretize(ep.problem_from_dict(data)), limit_load.LimitOptions(time_limit=5.0))
    assert 0 < seen["time_limit"] <= 5.0 - 0.3


def test_loads_no_solver_can_scale_are_refused_where_they_enter(disc, tmp_path, capsys):
    """check_scales refuses a mean contact pressure below 1e-100 E in a problem file; the
    same load given through with_force, a path's entry (CLI and ep.solve_path) or a
    depth's first guess is refused before any solve, naming what the user gave: a path
    ending at 1e-300 ran step 1 and then failed (or overflowed), a displacement of
    1e-300 was blamed on load.force, a force_guess of inf or "1" ran the search."""
    with pytest.raises(ep.InputError, match="load.force.*no solver can scale"):
        disc.with_force(1e-295)
    with pytest.raises(ep.InputError, match="forces: entry 2, 1e-300"):
        ep.solve_path(disc, [1000.0, 1e-300], "newton")
    path_file = write_toml(tmp_path / "p.toml", small_data(path=[1000.0, 1e-300]))
    assert main(["solve", str(path_file), "--method", "newton", "--out", str(tmp_path / "o"), "--quiet"]) == 2
    lines = error_lines(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith("error: load.path: entry 2, 1e-300"), lines
    depth_file = write_toml(tmp_path / "d.toml", small_data(displacement=1e-300))
    assert main(["solve", str(depth_file), "--method", "newton", "--out", str(tmp_path / "o"), "--quiet"]) == 2
    lines = error_lines(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith("error: load.displacement:"), lines
    for guess in (float("inf"), "1", True, 1e300):
        with pytest.raises(ep.InputError, match="force_guess"):
            ep.solve_depth(disc, 0.01, "newton", force_guess=guess)


def test_a_depth_path_reloads_after_a_lift_off_search_by_newton(disc):
    """docs/evolution.md's own depth path [0.02, 0.04, 0.02, 0.0]: each step looks for
    lift-off first at a floor force; at 1e-6 of the largest force newton's tol 1e-10
    could not be certified (a force balance of 7e-10: the state's stresses give each
    contact force a round-off of ROUND_OFF times the largest force), and step 2 ended
    max_iterations. The floor is now ROUND_OFF / tol of it, and every step converges."""
    assert floor_share(1e-10) == pytest.approx(ROUND_OFF / 1e-10) and floor_share(1e-6) == 1e-6
    result, searches = ep.solve_depth_path(disc, [0.02, 0.04, 0.02, 0.0], "newton")
    assert result.converged, [s.solution.message for s in result.steps]
    assert [s.lift_off for s in searches] == [False, False, False, True]
    assert result.steps[1].U == pytest.approx(0.04, rel=1e-6)


def test_arrays_in_another_layout_are_refused_not_reshaped(disc):
    """certify took any layout of the right size: a transposed u (d, n_nodes) was read
    with its components interleaved. The shape itself or the flat vector pass."""
    sol = ep.solve(disc, "newton")
    with pytest.raises(ep.InputError, match=r"u: expected shape \(\d+, 2\).*got \(2, \d+\)"):
        ep.certify(disc, sol.sigma, sol.xi, sol.u.T, sol.U)
    with pytest.raises(ep.InputError, match="sigma: expected shape"):
        ep.certify(disc, sol.sigma.T, sol.xi, sol.u, sol.U)
    flat = ep.certify(disc, sol.sigma.ravel(), sol.xi, sol.u.ravel(), sol.U)
    assert flat.worst == sol.kkt.worst


def test_no_slope_from_an_unloading_within_the_accuracy_of_U():
    """Unloading 3000 N to 2999.9999999 N moves U by 3e-11 of itself: by newton (KKT
    5e-11) its secant came out 2.07e5 where conic (KKT 3e-15) and a real unloading to
    1500 N give 3.08e5. With the first step's move below 1000 times U's certified
    accuracy, the unloading slope and Oliver-Pharr are null; a real unloading keeps them."""
    adisc = ep.discretize(ep.problem_from_dict(axisymmetric_data()))
    tiny = ep.solve_path(adisc, [3000.0, 2999.9999999], "newton")
    assert tiny.converged
    assert unloading_slope(tiny) is None and path_oliver_pharr(adisc, tiny) is None
    real = ep.solve_path(adisc, [3000.0, 1500.0], "newton")
    slope, op = unloading_slope(real), path_oliver_pharr(adisc, real)
    assert slope is not None and op is not None
    assert slope["S"] == pytest.approx((3000.0 - 1500.0) / (real.steps[0].U - real.steps[1].U))


def test_time_limit_bounds_a_whole_depth_search(tmp_path):
    """A depth solve makes several solves (8 for this one by uzawa on 60 x 30 cells,
    each under 0.3 s, the whole over 1 s): --time-limit 0.3 gave each its 0.3 s and
    exited 0. Now the solves share it: the search ends with status time_limit, exit 1."""
    data = small_data(displacement=0.05)
    data["mesh"]["divisions"] = [60, 30]
    problem = write_toml(tmp_path / "d.toml", data)
    out = tmp_path / "out"
    assert main(["solve", str(problem), "--method", "uzawa", "--time-limit", "0.3", "--out", str(out), "--quiet"]) == 1
    assert json.loads((out / "summary.json").read_text())["status"] == "time_limit"


def test_an_axisymmetric_contact_zone_is_centred_on_the_axis(tmp_path, capsys):
    """contact_center = [1.0] in an axisymmetric model was solved as the disc [0, 3]
    (the zone [1 - 2, 1 + 2] cut at the axis), not what the key says: refused naming
    it; [0] (the default) is accepted."""
    for centre, code in (([1.0], 2), ([0.0], 0)):
        data = axisymmetric_data()
        data["mesh"]["contact_center"] = centre
        problem = write_toml(tmp_path / "a.toml", data)
        assert main(["solve", str(problem), "--method", "newton", "--out", str(tmp_path / "o"), "--quiet"]) == code
        if code == 2:
            lines = error_lines(capsys.readouterr().err)
            assert len(lines) == 1 and lines[0].startswith("error: mesh.contact_center: in an axisymmetric model")


def test_check_bounds_on_an_axisymmetric_answer_brackets_it(tmp_path, capsys):
    """check --bounds on an axisymmetric answer (refused while the bounds refused
    axisymmetric models) now brackets it with the axisymmetric bounds: the energy of the
    answer's own field lies above the equilibrium element's lower bound (weak duality),
    both certified, and U lies in its bracket."""
    data = axisymmetric_data()
    problem = write_toml(tmp_path / "a.toml", data)
    disc = ep.discretize(ep.problem_from_dict(data))
    sol = ep.solve(disc, "newton")
    np.savez(tmp_path / "a.npz", u=sol.u, U=sol.U)
    out = tmp_path / "out"
    assert main(["check", str(problem), str(tmp_path / "a.npz"), "--bounds", "--quiet", "--out", str(out)]) == 0
    record = json.loads((out / "summary.json").read_text())
    assert record["bounds_certified"] and record["energy_lower"] <= record["energy_upper"]
    assert record["U_lower"] <= sol.U <= record["U_upper"]


def test_a_suite_reads_every_problem_file_before_any_run(tmp_path, capsys):
    """A suite folder holding a problem with nu = 0.6 ran, timed that file as a failure
    ('error: reading the problem') and exited 1; a depth-controlled file was 'refused'
    with advice for Python. Both are now bad input before any run: exit 2, one line
    naming the file and the field, no profile written."""
    suite = tmp_path / "suite"
    suite.mkdir()
    write_toml(suite / "a.toml", small_data())
    for bad, field in ((dict(small_data(), material={**small_data()["material"], "nu": 0.6}), "material.nu"),
                       (small_data(displacement=0.01), "load.displacement")):
        write_toml(suite / "b.toml", bad)
        out = tmp_path / "profile"
        assert main(["compare", str(suite), "--method", "newton", "--out", str(out), "--quiet"]) == 2
        lines = error_lines(capsys.readouterr().err)
        assert len(lines) == 1 and lines[0].startswith(f"error: b.toml: {field}:"), lines
        assert not out.exists()


def test_a_graded_half_model_keeps_its_obstacle_on_the_axis(tmp_path, capsys):
    """The graded block with its default boundary is a symmetric half about x = 0 (u_x = 0
    on xmin): an obstacle centred at x = 1 was solved as if mirrored there, silently.
    Refused naming obstacle.center; centred on the axis it solves."""
    pytest.importorskip("gmsh")
    data = {"mesh": {"generator": "graded", "size": [20.0, 20.0], "contact_radius": 2.0, "h_contact": 0.5,
                     "h_far": 5.0},
            "material": {"E": 200000.0, "nu": 0.3, "yield_stress": 1200.0, "hardening": 10000.0},
            "obstacle": {"shape": "cylinder", "radius": 40.0, "center": [1.0]}, "load": {"force": 2000.0}}
    with pytest.raises(ep.InputError, match="obstacle.center: is \\[1.0\\]: the graded block"):
        ep.problem_from_dict(data)
    data["obstacle"]["center"] = [0.0]
    assert list(ep.problem_from_dict(data).obstacle.center) == [0.0]


def test_a_store_that_cannot_be_written_names_out(tmp_path):
    """A file-size limit (RLIMIT_FSIZE, as a full disk acts) met while campaign creates its
    store's index: sqlite's 'disk I/O error' was reported as 'is damaged: cannot read
    index.sqlite ... no such table' (the clean-up's read of the empty index hid the
    write's error). Now exit 2 naming --out as the place written to, nothing left behind."""
    import os
    import subprocess
    import sys

    data = small_data()
    data["campaign"] = {"name": "full"}
    data["sweep"] = {"load.force": [2000.0, 4315.0]}
    campaign = write_toml(tmp_path / "c.toml", data)
    out = tmp_path / "store"
    code = ("import resource, sys; from elastoplast.cli.main import main; "
            "resource.setrlimit(resource.RLIMIT_FSIZE, (2048, 2048)); "
            f"sys.exit(main(['campaign', {str(campaign)!r}, '--out', {str(out)!r}, '--workers', '1', '--quiet']))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --out: cannot write the store"), lines
    assert not out.exists()


def test_objects_made_by_replace_are_checked_as_a_file_is(disc):
    """dataclasses.replace bypassed the file's checks: a Material with nu = 0.7 (bulk
    modulus E / (3 (1 - 2 nu)) < 0) was discretised and solved, a cone of 90 degrees
    (tan 90 = 1.6e16: a flat obstacle) discretised, a force "1" reached numpy (TypeError,
    exit 3). Each is an InputError naming the field, as in a problem file."""
    problem = disc.problem
    with pytest.raises(ep.InputError, match=r"material.nu: must lie in \(-1, 0.5\), got 0.7"):
        replace(problem, material=replace(problem.material, nu=0.7))
    with pytest.raises(ep.InputError, match="material.E: must be a number"):
        ep.Material("1", 0.3, 1.0, 1.0)
    assert ep.Material(1.0, 0.3, float("inf"), 0.0).yield_stress == float("inf")  # the elastic body (osqp-elastic)
    with pytest.raises(ep.InputError, match="load.force: must be a finite number, got '1'"):
        replace(problem, force="1")
    with pytest.raises(ep.InputError, match="load.displacement: must be a finite number"):
        replace(problem, displacement=float("nan"))
    cone = ep.problem_from_dict(axisymmetric_data()).obstacle
    with pytest.raises(ep.InputError, match=r"obstacle.half_angle: must lie in \(0, 90\)"):
        replace(cone, shape="cone", half_angle=90.0)
    with pytest.raises(ep.InputError, match="obstacle.radius: must be a finite number > 0"):
        replace(problem.obstacle, radius=-1.0)


def test_a_depth_beyond_small_strains_says_why_no_force_is_found():
    """A cone (70 degrees) 0.01 into the 8 x 8 meridian mesh: the answers that reach that
    depth leave the small-strain model at the tip (|eps| > 0.1, status failed), so the
    search ran out of its 60 solves and said only 'no force found'; it now names the
    reason the forces above its last converged one fail."""
    data = axisymmetric_data(displacement=0.01)
    data["obstacle"] = {"shape": "cone", "half_angle": 70.0}
    adisc = ep.discretize(ep.problem_from_dict(data))
    with pytest.raises(ep.InputError, match="no force found .* the forces above it fail: .*small-strain"):
        ep.solve_depth(adisc, 0.01, "newton")


def test_a_plug_in_that_ends_its_worker_process_is_a_failed_case(tmp_path, monkeypatch, capfd):
    """A plug-in calling os._exit in a Dask worker (no Python exception to catch) ended
    the campaign in the workers' warm-up: 'internal error, CommClosedError', exit 3, with
    distributed's raw log line before it. The warm-up is best effort now and the scheduler
    quiet: the case is stored as failed (the worker lost each time it ran it), exit 1."""
    (tmp_path / "ep_ends.py").write_text("import os\n\ndef run(disc, options):\n    os._exit(1)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path) + ":" + str(ROOT))
    data = small_data()
    data["mesh"]["divisions"] = [8, 4]
    data["campaign"] = {"name": "ends"}
    data["solver"] = {"method": "ep_ends:run"}
    data["sweep"] = {"load.force": [2000.0]}
    campaign = write_toml(tmp_path / "c.toml", data)
    assert main(["campaign", str(campaign), "--out", str(tmp_path / "store"), "--workers", "1", "--quiet"]) == 1
    err = capfd.readouterr().err
    assert "internal error" not in err and " - distributed." not in err and "ERROR" not in err, err
    assert "KilledWorker" in err


def test_small_strain_note_said_once_when_an_answer_is_judged_again():
    """An outside method's Solution already carries the small-strain note; judging it
    again (make_solution with its message) appended the note a second time. Said once."""
    data = axisymmetric_data()
    disc = ep.discretize(ep.problem_from_dict(data))
    sol = ep.solve(disc, "newton")
    big = 1e4 * np.asarray(sol.u)  # strains far beyond 0.1
    first = make_solution(disc, method="x", status=ep.Status.CONVERGED, sigma=sol.sigma, xi=sol.xi,
                          u_free=disc.free_displacement(big), U=sol.U, iterations=0, timings={})
    again = make_solution(disc, method="x", status=ep.Status.CONVERGED, sigma=sol.sigma, xi=sol.xi,
                          u_free=disc.free_displacement(big), U=sol.U, iterations=0, timings={}, message=first.message)
    assert first.status is again.status is ep.Status.FAILED
    assert "small-strain model" in first.message and again.message == first.message
