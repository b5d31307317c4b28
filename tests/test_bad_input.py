"""Issue 9, bad input: no hang, no wrong answer called converged, no traceback,
safe output, one option path. Each test names the exact input the issue
reported and asserts the exit code and the field the message names."""

from __future__ import annotations

import dataclasses
import json
import math
import time

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.solvers.registry import Method
from elastoplast.cli.main import main
from elastoplast.solvers.loop import within_tolerance
from elastoplast.options import LOOSEST_TOL, MAX_ITER_CEILING, TIGHTEST_TOL
from elastoplast.io.output import OUTPUT_MARKER, json_text
from elastoplast.studies.results import write_results

from conftest import PROBLEMS, build
from test_cli import small_cylinder, write_toml

ITERATIVE = ["uzawa", "uzawa-fast", "newton"]


@pytest.fixture
def problem_file(tmp_path):
    return write_toml(tmp_path / "base.toml", small_cylinder())


@pytest.fixture(scope="module")
def small_disc():
    return build(small_cylinder())


def run(capsys, *argv) -> tuple[int, str]:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    return code, err[-1] if err else ""


# ---------------------------------------------------------------------------
# hangs: every loop is bounded, and no option can unbound it
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("method", ITERATIVE)
@pytest.mark.parametrize("flags,field", [
    (["--tol", "0", "--max-iter", "-1"], "--tol"),
    (["--tol", "nan"], "--tol"),
    (["--tol", "1e-30"], "--tol"),
    (["--max-iter", "-1"], "--max-iter"),
    (["--max-iter", "0"], "--max-iter"),
    (["--max-iter", "4294967296"], "--max-iter"),
    (["--time-limit", "-1"], "--time-limit"),
    (["--time-limit", "inf"], "--time-limit"),
])
def test_unbounding_options_are_refused_before_any_work(problem_file, tmp_path, capsys, method, flags, field):
    """The issue's hangs (`--tol 0 --max-iter -1`, `--tol nan`, `--tol 1e-30`)
    and their relatives: exit 2, one line naming the flag, no output written."""
    t0 = time.perf_counter()
    code, line = run(capsys, "solve", problem_file, "--method", method, "--quiet", "--out", tmp_path / "o", *flags)
    assert code == 2 and line.startswith(f"error: {field}:"), line
    assert not (tmp_path / "o").exists()
    assert time.perf_counter() - t0 < 10.0  # refused, not run


@pytest.mark.parametrize("method", ["conic", *ITERATIVE])
def test_time_limit_stops_every_method(small_disc, method):
    """A wall-clock limit far below one solve ends each method with status
    time_limit (or an honest max_iterations for one-step interior points),
    never converged, and returns the last candidate with its residuals."""
    sol = ep.solve(small_disc.with_force(6 * small_disc.force), method, time_limit=1e-3)
    assert sol.status in (ep.Status.TIME_LIMIT, ep.Status.MAX_ITERATIONS, ep.Status.FAILED), sol.message
    assert not within_tolerance(sol.kkt, 1e-6)


def test_tolerance_range_is_the_documented_one():
    """One range for every method: [TIGHTEST_TOL, LOOSEST_TOL]; iteration counts capped."""
    for method, m in ep.METHODS.items():
        assert ep.method_options(method, {"tol": TIGHTEST_TOL}).tol == TIGHTEST_TOL
        assert ep.method_options(method, {"tol": LOOSEST_TOL}).tol == LOOSEST_TOL
        for bad in (0.0, -1e-6, 2 * LOOSEST_TOL, TIGHTEST_TOL / 2, math.nan, math.inf, True, "1e-6"):
            with pytest.raises(ep.InputError) as exc:
                ep.method_options(method, {"tol": bad})
            assert exc.value.field == "tol"
        assert m.options.specs()["max_iter"].hi <= MAX_ITER_CEILING


# ---------------------------------------------------------------------------
# wrong answers called converged
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("method", ITERATIVE)
def test_loose_tolerance_cannot_call_the_start_converged(problem_file, tmp_path, capsys, method):
    """The issue: `--tol 5` returned U = 0 after 0 iterations as converged.
    A tolerance above LOOSEST_TOL is refused (exit 2, names --tol)."""
    code, line = run(capsys, "solve", problem_file, "--method", method, "--tol", "5", "--quiet", "--out", tmp_path / "o")
    assert code == 2 and line.startswith("error: --tol:"), line


def test_the_loosest_tolerance_still_rejects_the_trivial_answer(small_disc):
    """At u = 0, U = 0 the force balance residual is |0 - F| / F = 1 (the
    certificate's definition), far above LOOSEST_TOL: the trivial answer can
    never pass."""
    z = np.zeros
    kkt = ep.certify(small_disc, z((small_disc.n_elements, small_disc.k)), z(small_disc.n_elements),
                     z((small_disc.mesh.n_nodes, small_disc.dim)), 0.0)
    assert kkt.force_balance == 1.0
    assert not within_tolerance(kkt, LOOSEST_TOL)


def test_nan_anywhere_is_never_small():
    """`KKTResiduals.worst` ignored a NaN unless it came first."""
    fields = [f.name for f in dataclasses.fields(ep.KKTResiduals)]
    for i in range(len(fields)):
        values = {name: 1e-12 for name in fields}
        values[fields[i]] = math.nan
        kkt = ep.KKTResiduals(**values)
        assert math.isnan(kkt.worst), fields[i]
        assert not within_tolerance(kkt, LOOSEST_TOL)


def test_non_finite_answer_is_not_converged(small_disc):
    """make_solution downgrades a CONVERGED candidate holding NaN (whatever the method claimed)."""
    sol = ep.solve(small_disc, "newton")
    assert sol.converged
    u_free = small_disc.free_displacement(sol.u)
    u_free[0] = np.nan
    bad = ep.make_solution(small_disc, method="test", status=ep.Status.CONVERGED, sigma=sol.sigma, xi=sol.xi,
                           u_free=u_free, U=sol.U, iterations=0, timings={})
    assert bad.status is ep.Status.FAILED and "non-finite" in bad.message


# ---------------------------------------------------------------------------
# one option path
# ---------------------------------------------------------------------------


def test_unknown_or_meaningless_options_are_refused_everywhere(small_disc, problem_file, tmp_path, capsys):
    """Python keywords, [solver] table, command-line flags and --option: the
    same check, naming the option as the user wrote it."""
    with pytest.raises(ep.InputError) as exc:
        ep.solve(small_disc, "conic", polish=False, no_such_option=1)
    assert exc.value.field == "no_such_option"
    with pytest.raises(ep.InputError) as exc:
        ep.solve(small_disc, "newton", rho=1e-6)
    assert exc.value.field == "rho"
    code, line = run(capsys, "solve", problem_file, "--method", "newton", "--rho", "1e-6", "--out", tmp_path / "a")
    assert code == 2 and line.startswith("error: --rho: method 'newton' has no option 'rho'"), line
    code, line = run(capsys, "solve", problem_file, "--option", "penalty=2", "--out", tmp_path / "b")
    assert code == 2 and line.startswith("error: --option penalty:"), line
    data = small_cylinder()
    data["solver"] = {"method": "uzawa-fast", "rho": 1.0}
    code, line = run(capsys, "solve", write_toml(tmp_path / "s.toml", data), "--out", tmp_path / "c")
    assert code == 2 and line.startswith("error: solver.rho:"), line


def test_option_flag_reaches_the_method(problem_file, tmp_path, capsys):
    """`--option polish=false` gives the raw interior-point answer (its message
    has no polishing), `--option polish=true` the polished one."""
    for value, polished in (("false", False), ("true", True)):
        out = tmp_path / value
        main(["solve", str(problem_file), "--quiet", "--out", str(out), "--option", f"polish={value}"])
        assert ("polished" in json.loads((out / "summary.json").read_text())["message"]) is polished


# ---------------------------------------------------------------------------
# tracebacks and exit codes
# ---------------------------------------------------------------------------


def test_out_pointing_at_a_file_is_refused_before_the_solve(problem_file, tmp_path, capsys, monkeypatch):
    target = tmp_path / "a-file"
    target.write_text("mine")

    def must_not_run(*args, **kwargs):
        raise AssertionError("the solve ran before --out was checked")

    monkeypatch.setattr("elastoplast.solvers.registry.solve", must_not_run)
    code, line = run(capsys, "solve", problem_file, "--out", target)
    assert code == 2 and line.startswith("error: --out:") and "not a folder" in line, line
    assert target.read_text() == "mine"


def test_out_holding_other_files_is_refused(problem_file, tmp_path, capsys):
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("keep me")
    code, line = run(capsys, "solve", problem_file, "--out", folder)
    assert code == 2 and line.startswith("error: --out:") and "notes.txt" in line, line
    assert (folder / "notes.txt").read_text() == "keep me"


def test_internal_error_is_one_line_with_exit_3(problem_file, tmp_path, capsys, monkeypatch):
    def broken(disc, options):
        raise ZeroDivisionError("deep inside a solver")

    monkeypatch.setitem(ep.METHODS, "conic", Method("conic", broken, ep.ConicOptions, "broken"))
    monkeypatch.delenv("ELASTOPLAST_DEBUG", raising=False)
    code = main(["solve", str(problem_file), "--quiet", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 3 and len(err) == 1 and "ZeroDivisionError: deep inside a solver" in err[0], err
    assert not (tmp_path / "o").exists()  # nothing half-written


def test_corrupt_store_is_an_input_error(tmp_path, capsys):
    store = tmp_path / "store"
    store.mkdir()
    (store / "index.sqlite").write_bytes(b"this is not an SQLite database" * 100)
    code, line = run(capsys, "compare", store, "--method", "conic", "--workers", "1", "--quiet")
    assert code == 2 and line.startswith("error: STORE:") and "damaged" in line, line
    code, line = run(capsys, "campaign", PROBLEMS / "campaign_2d.toml", "--out", store, "--workers", "1")
    assert code == 2 and line.startswith("error: --out:"), line  # campaign's store is its --out


@pytest.mark.parametrize("flags,field", [
    (["--workers", "-2"], "--workers"), (["--workers", "0"], "--workers"), (["--workers", "100000"], "--workers"),
    (["--scheduler", "not a url"], "--scheduler"), (["--scheduler", "tcp://127.0.0.1:99999"], "--scheduler"),
])
def test_bad_cluster_arguments_are_refused_and_leave_no_store(tmp_path, capsys, flags, field):
    """The issue: `--workers -2` waited forever; `--scheduler "not a url"` gave a traceback."""
    code, line = run(capsys, "campaign", PROBLEMS / "campaign_2d.toml", "--out", tmp_path / "store", "--quiet", *flags)
    assert code == 2 and line.startswith(f"error: {field}:"), line
    assert not (tmp_path / "store").exists()


def test_unreachable_scheduler_leaves_no_store(tmp_path, capsys):
    code, line = run(capsys, "campaign", PROBLEMS / "campaign_2d.toml", "--out", tmp_path / "store", "--quiet",
                     "--scheduler", "tcp://127.0.0.1:9")  # the discard port: nothing listens
    assert code == 2 and line.startswith("error: --scheduler:"), line
    assert not (tmp_path / "store").exists()


# ---------------------------------------------------------------------------
# output
# ---------------------------------------------------------------------------


def test_reused_out_holds_only_the_new_runs_files(problem_file, tmp_path):
    """The issue: a re-used --out kept an earlier method's convergence plot."""
    out = tmp_path / "out"
    assert main(["solve", str(problem_file), "--method", "uzawa", "--quiet", "--out", str(out)]) == 0
    assert (out / "convergence.png").is_file()
    assert main(["solve", str(problem_file), "--method", "conic", "--quiet", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == sorted([OUTPUT_MARKER, "solution.vtu", "summary.json"])
    assert json.loads((out / "summary.json").read_text())["method"] == "conic"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out.")]  # no temporary folder left


def test_failed_write_leaves_the_earlier_output_intact(small_disc, tmp_path, monkeypatch):
    out = tmp_path / "out"
    sol = ep.solve(small_disc, "conic")
    write_results(out, small_disc, sol)
    before = (out / "summary.json").read_text()

    def broken_vtu(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("elastoplast.studies.results.write_vtu", broken_vtu)
    with pytest.raises(OSError):
        write_results(out, small_disc, sol)
    assert (out / "summary.json").read_text() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_summary_is_strict_json_even_with_non_finite_values(small_disc, tmp_path):
    """The issue: NaN/Infinity in summary.json, which strict readers refuse."""
    sol = ep.solve(small_disc, "conic")
    bad = dataclasses.replace(sol, U=math.inf, contact_pressure=np.full_like(sol.contact_pressure, np.nan))
    write_results(tmp_path / "o", small_disc, bad)
    text = (tmp_path / "o" / "summary.json").read_text()

    def refuse(constant):
        raise ValueError(f"non-standard JSON constant {constant}")

    data = json.loads(text, parse_constant=refuse)
    assert data["U"] is None and data["max_contact_pressure"] is None
    assert json.loads(json_text({"a": [np.float64("nan"), np.inf, 1.5]})) == {"a": [None, None, 1.5]}


def test_absurd_force_is_refused(problem_file, tmp_path, capsys):
    """The issue's `force = 1e300`: a mean pressure 1e3 E and more has no small-strain meaning."""
    data = small_cylinder()
    data["load"]["force"] = 1e300
    code, line = run(capsys, "solve", write_toml(tmp_path / "f.toml", data), "--quiet", "--out", tmp_path / "o")
    assert code == 2 and line.startswith("error: load.force:"), line


def test_campaign_checks_problem_dependent_options_before_running(tmp_path):
    """Uzawa's step must lie below 2 / lambda_max(C) of the material: a campaign point
    beyond it is refused when the campaign is loaded, naming the axis."""
    from elastoplast.studies.campaign import load_campaign

    path = tmp_path / "c.toml"
    path.write_text(f'[campaign]\nproblem = "{PROBLEMS / "cylinder_2d.toml"}"\n[mesh]\ndivisions = [20, 10]\n'
                    '[sweep]\nmethod = ["uzawa"]\n"solver.rho" = [1e-6, 1.0]\n'
                    '"material.hardening" = [10000.0]\n"load.force" = [1000.0]\n')
    with pytest.raises(ep.InputError) as exc:
        load_campaign(path)
    assert exc.value.field == "sweep.solver.rho" and "1.0" in exc.value.message


@pytest.mark.parametrize("method", ["conic", *ITERATIVE])
def test_tiny_force_is_solved_by_every_method(method):
    """F = 1e-12 on the cylinder: displacements 1e-15 of the obstacle's height at the
    edge of the contact zone. Every method used to fail here (conic called it
    'above the limit load', Uzawa diverged). Hencky's law is linear below first yield,
    so U scales with F; the check is the certificate at the method's own tol and
    U / F against the same problem at F = 1e-2 (both elastic, single-node contact)."""
    small = build(small_cylinder())
    tiny, ref = small.with_force(1e-12), small.with_force(1e-2)
    sol, sol_ref = ep.solve(tiny, method), ep.solve(ref, method)
    assert sol.converged and sol_ref.converged, (sol.message, sol_ref.message)
    assert not sol.plastic.any()
    assert sol.U / 1e-12 == pytest.approx(sol_ref.U / 1e-2, rel=1e-5)


def test_newton_starts_feasible_when_the_obstacle_starts_above_the_plane():
    """psi < 0 at a contact node (the conservative obstacle of the upper bound lowers psi
    below 0 on a coarse ungraded mesh): u = 0 is not in K_h there, and Newton diverged at
    iteration 0. It now starts from the projection of 0 and agrees with the conic
    reference (the same discrete problem: U to 1e-8)."""
    from elastoplast.bounds.upper import conservative_discretization

    data = small_cylinder()
    data["mesh"].update(divisions=[10, 5], grading=1.0)
    disc = conservative_discretization(build(data))
    assert disc.psi.min() < 0
    newton, conic = ep.solve(disc, "newton"), ep.solve(disc, "conic")
    assert newton.converged and conic.converged
    assert newton.U == pytest.approx(conic.U, rel=1e-8)


# ---------------------------------------------------------------------------
# the later commands (bounds, limit, adapt, campaign [adapt]) and the Python API
# ---------------------------------------------------------------------------


def test_limit_with_a_tiny_time_limit_says_what_it_has(tmp_path, capsys):
    """`limit --time-limit 1e-9` stopped the static program before any load: the
    certificate then divided by a zero scale (exit 3, ZeroDivisionError). F_c >= 0
    is all such a run shows: exit 1, F_lower = 0, not certified, strict JSON."""
    from test_commands import half_punch, strict_json

    problem = write_toml(tmp_path / "p.toml", half_punch())
    code, line = run(capsys, "limit", problem, "--time-limit", "1e-9", "--out", tmp_path / "l", "--quiet")
    assert code == 1, line
    s = strict_json(tmp_path / "l" / "summary.json")
    assert s["F_lower"] == 0.0 and s["lower_certified"] is False and s["certified"] is False
    assert "no positive load" in s["message"]


def test_sigterm_unwinds_like_ctrl_c(tmp_path):
    """`timeout` or a batch scheduler sends SIGTERM: Python's default ended the process
    on the spot and left the staged folder (`.a.tmp-*`) beside --out, which then made
    the parent folder look foreign. Now exit 143, one line, nothing left behind."""
    import signal
    import subprocess
    import sys

    data = small_cylinder()
    problem = write_toml(tmp_path / "p.toml", data)
    work = tmp_path / "work"
    work.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "elastoplast", "adapt", str(problem), "--rtol", "1e-6",
                             "--out", str(work / "a"), "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            cwd=tmp_path, text=True)
    try:
        deadline = time.monotonic() + 60
        while not list(work.glob(".a.tmp-*")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # the staged folder exists once the run is under way
        assert proc.poll() is None, proc.communicate()[1]
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 143 and err.strip().splitlines()[-1] == "terminated", err
    assert list(work.iterdir()) == []


def test_option_of_the_wrong_type_is_refused(problem_file, tmp_path, capsys):
    """`--option initial=1` (Uzawa's warm start takes a Solution) reached the solver:
    exit 3, AttributeError. Now refused naming the option."""
    code, line = run(capsys, "solve", problem_file, "--method", "uzawa", "--option", "initial=1", "--quiet",
                     "--out", tmp_path / "o")
    assert code == 2 and line.startswith("error: --option initial:") and "Solution" in line, line
    with pytest.raises(ep.InputError) as exc:
        ep.UzawaOptions(initial={"u": 1})
    assert exc.value.field == "initial"


def test_campaign_refuses_an_adaptive_target_with_h0_before_running(tmp_path):
    """An `[adapt]` table on an H = 0 problem ran, and was stored as a failed case;
    adapt cannot run it, so the point is refused when the campaign is loaded."""
    from elastoplast.studies.campaign import load_campaign
    from test_commands import half_punch

    write_toml(tmp_path / "p.toml", half_punch())
    path = tmp_path / "c.toml"
    path.write_text('[campaign]\nproblem = "p.toml"\n[adapt]\nrtol = 0.3\n[sweep]\n"load.force" = [100.0]\n')
    with pytest.raises(ep.InputError) as exc:
        load_campaign(path)
    assert "material.hardening" in str(exc.value)


def _api_calls(disc):
    from elastoplast.adapt.loop import adapt
    from elastoplast.references.certified import certified_bounds

    return {
        "with_force(-1)": (lambda: disc.with_force(-1.0), "load.force"),
        "with_force(nan)": (lambda: disc.with_force(float("nan")), "load.force"),
        "with_force(inf)": (lambda: disc.with_force(float("inf")), "load.force"),
        "certified_bounds(solution='x')": (lambda: certified_bounds(disc, solution="x"), "solution"),
        "certified_bounds(lower_options={'tol': 1})": (
            lambda: certified_bounds(disc, lower_options={"tol": 1}, bracket=False), "lower_options.tol"),
        "adapt(disc)": (lambda: adapt(disc), "problem"),
        "adapt(problem, 'fast')": (lambda: adapt(disc.problem, "fast"), "options"),
        "refine(None, [0])": (lambda: ep.refine(None, [0]), "mesh"),
        # 2^40 children of one triangle: was allocated until the machine killed the process
        "refine(mesh, [0], bisections=40)": (lambda: ep.refine(disc.mesh, [0], bisections=40), "bisections"),
        # wrapped around in an int16 counter: the mesh came back unrefined, silently
        "refine(mesh, [0], bisections=10**9)": (lambda: ep.refine(disc.mesh, [0], bisections=10**9), "bisections"),
        "discretize(dict)": (lambda: ep.discretize({"mesh": {}}), "problem"),
        "load_problem(None)": (lambda: ep.load_problem(None), "problem"),
        "read_mesh(None)": (lambda: ep.read_mesh(None), "mesh.file"),
        "read_toml(5)": (lambda: ep.read_toml(5), "problem"),
        "solve_lower_bound(disc.problem)": (lambda: ep.solve_lower_bound(disc.problem), "disc"),
    }


@pytest.mark.parametrize("name", list(_api_calls(None)))
def test_python_entry_points_refuse_bad_arguments_naming_them(small_disc, name):
    """Each of these raised TypeError, ValueError or AttributeError from deep inside
    (or, for with_force, was accepted and solved into a FAILED answer)."""
    call, field = _api_calls(small_disc)[name]
    with pytest.raises(ep.InputError) as exc:
        call()
    assert exc.value.field == field, exc.value


def test_python_entry_points_take_options_as_mappings():
    """One option path: a mapping is checked like an options object (was AttributeError)."""
    from elastoplast.bounds.limit_load import kinematic_limit_load

    punch = build(__import__("test_commands").half_punch())
    with pytest.raises(ep.InputError) as exc:
        kinematic_limit_load(punch, {"order": 3})
    assert exc.value.field == "options.order"
    assert kinematic_limit_load(punch, {"order": 1}).order == 1


def test_limit_refuses_a_mesh_too_large_before_the_kinematic_program(tmp_path, capsys, monkeypatch):
    """A 3D box of 192,000 tetrahedra with H = 0: the kinematic (P2) program ran first and
    allocated until the process aborted (`memory allocation failed`, exit 134); 12,288
    ran past a 20 s --time-limit for minutes. The static program's size limit (Clarabel,
    8,000 tetrahedra) now refuses the mesh before either program runs."""
    import elastoplast.bounds.limit_load as limit

    def must_not_run(*args, **kwargs):
        raise AssertionError("the kinematic program ran before the size check")

    monkeypatch.setattr(limit, "kinematic_limit_load", must_not_run)
    data = {"mesh": {"generator": "box", "size": [12.0, 12.0, 6.0], "divisions": [16, 16, 6], "contact_radius": 4.5},
            "material": {"E": 200000.0, "nu": 0.3, "yield_stress": 1500.0, "hardening": 0.0},
            "obstacle": {"shape": "sphere", "radius": 40.0}, "load": {"force": 7330.0}}
    code, line = run(capsys, "limit", write_toml(tmp_path / "p.toml", data), "--out", tmp_path / "l", "--quiet")
    assert code == 2 and line.startswith("error: mesh:") and "9,216 elements" in line, line
    assert not (tmp_path / "l").exists()


def test_output_folder_has_the_permissions_of_a_new_folder(problem_file, tmp_path, capsys):
    """The staged folder came from mkdtemp (mode 0700), so every output folder was
    unreadable to the user's group, unlike one made by mkdir; now it follows the umask."""
    import os

    umask = os.umask(0o022)
    os.umask(umask)
    assert main(["solve", str(problem_file), "--quiet", "--out", str(tmp_path / "o")]) == 0
    assert (tmp_path / "o").stat().st_mode & 0o777 == 0o777 & ~umask


def test_full_disk_names_out_and_keeps_the_earlier_output(problem_file, tmp_path, capsys, monkeypatch):
    """Writing the output on a full disk was an 'internal error' (exit 3, OSError): it is
    the place written to, named like any other bad --out, and the earlier output stays."""
    import errno

    out = tmp_path / "o"
    assert main(["solve", str(problem_file), "--quiet", "--out", str(out)]) == 0
    before = sorted(p.name for p in out.iterdir())
    capsys.readouterr()

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr("elastoplast.studies.results.write_vtu", full)
    code, line = run(capsys, "solve", problem_file, "--quiet", "--out", out)
    assert code == 2 and line.startswith("error: --out:") and "No space left" in line, line
    assert sorted(p.name for p in out.iterdir()) == before
    assert [p.name for p in tmp_path.iterdir() if ".tmp-" in p.name] == []


def test_closed_stdout_is_not_an_internal_error(problem_file, tmp_path):
    """`elastoplast solve ... | head -c 0`: printing the report raised BrokenPipeError,
    reported as an internal error (exit 3). The files are written: exit 141, as the
    shell gives for SIGPIPE, and nothing on stderr."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "elastoplast", "solve", str(problem_file), "--quiet", "--out",
                             str(tmp_path / "o")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path)
    proc.stdout.close()  # the reader has gone before anything was printed
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.wait(timeout=60) == 141 and err == "", err
    assert (tmp_path / "o" / "summary.json").exists()


def test_adapt_uses_or_names_the_files_solver_table(tmp_path, capsys):
    """adapt dropped the file's [solver] options silently (tol = 1e-12 ran at 1e-8,
    max_iter = 3 vanished). Now tol is the P1 tolerance (checked against adapt's range,
    named solver.tol) and the others are named in a warning."""
    data = small_cylinder()
    data["mesh"]["divisions"] = [10, 5]
    data["solver"] = {"tol": 1e-12, "max_iter": 3}
    out = tmp_path / "a"
    code = main(["adapt", str(write_toml(tmp_path / "p.toml", data)), "--rtol", "0.5", "--no-uniform", "--quiet",
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 0 and "warning: solver.max_iter: not used by adapt" in err, err
    assert json.loads((out / "adapt.json").read_text())["options"]["tol"] == 1e-12
    data["solver"] = {"tol": 1e-3}
    code, line = run(capsys, "adapt", write_toml(tmp_path / "q.toml", data), "--quiet", "--out", tmp_path / "b")
    assert code == 2 and line.startswith("error: solver.tol:"), line
    assert not (tmp_path / "b").exists()


def test_lower_bound_that_cannot_fit_in_memory_is_refused_before_the_solve(problem_file, tmp_path, capsys,
                                                                            monkeypatch, small_disc):
    """The lower-bound programs had no memory estimate: a mesh within the size limit but
    beyond the machine's memory was killed mid-program. The estimate is
    LOWER_BOUND_BYTES_PER_ELEMENT per element (x SEQUENCE_MEMORY_FACTOR with the U
    bracket, two more programs in the same process); 2 MB cannot hold the 400-triangle
    program (18 MB), so `bounds` refuses before the P1 solve and writes nothing."""
    from elastoplast.adapt.records import AdaptOptions
    from elastoplast.adapt.budget import lower_bound_limit
    from elastoplast.limits import MEMORY_ENV
    from elastoplast.bounds.lower import LOWER_BOUND_BYTES_PER_ELEMENT, SEQUENCE_MEMORY_FACTOR, LowerBoundOptions
    from elastoplast.bounds.equilibrium.bound import solve_lower_bound
    from elastoplast.errors import InputError

    monkeypatch.setenv(MEMORY_ENV, "2M")
    code, line = run(capsys, "bounds", problem_file, "--quiet", "--out", tmp_path / "b")
    assert code == 2 and line.startswith("error: mesh:") and "lower bound" in line and "needs about" in line, line
    assert "2 MiB available" in line and f"{MEMORY_ENV}=2M" in line, line
    assert not (tmp_path / "b").exists()
    with pytest.raises(InputError) as info:
        solve_lower_bound(small_disc, LowerBoundOptions())
    assert info.value.field == "mesh"
    # the adaptive loop plans its meshes under the same estimate (several programs in one process)
    assert lower_bound_limit(2, AdaptOptions()) == 2 * 2**20 // int(SEQUENCE_MEMORY_FACTOR * LOWER_BOUND_BYTES_PER_ELEMENT[2])
    monkeypatch.setenv(MEMORY_ENV, "1T")
    assert lower_bound_limit(2, AdaptOptions(lower_max_elements=500)) == 500


def test_adapt_with_closed_stdout_still_writes_its_files(tmp_path):
    """`elastoplast adapt ... | head -c 0`: adapt prints its steps while its files are
    still staged; the BrokenPipeError removed the staged folder, so nothing was written
    for a run that had finished. Now stdout goes to devnull from the first broken write,
    the run goes on: exit 141 and the output is in place."""
    import subprocess
    import sys

    data = small_cylinder()
    data["mesh"]["divisions"] = [10, 5]
    problem = write_toml(tmp_path / "p.toml", data)
    proc = subprocess.Popen([sys.executable, "-m", "elastoplast", "adapt", str(problem), "--rtol", "0.2", "--no-uniform",
                             "--bracket", "never", "--quiet", "--out", str(tmp_path / "a")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=tmp_path)
    proc.stdout.close()
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.wait(timeout=120) == 141, err
    assert (tmp_path / "a" / "summary.json").exists() and (tmp_path / "a" / "adapt.json").exists()


def test_adapt_plans_under_memory_and_keeps_its_steps_when_refused_mid_run(monkeypatch):
    """A start mesh whose lower-bound programs (x SEQUENCE_MEMORY_FACTOR, several in one
    process) cannot fit is refused before any work, naming the memory; a refusal of a
    later mesh (memory taken by others since the plan) ends the run at the previous
    mesh instead of losing every step; the U bracket of a refused program is NaN."""
    import warnings

    from elastoplast.adapt.records import AdaptOptions
    from elastoplast.adapt.loop import adapt
    from elastoplast.adapt.budget import lower_bound_budget
    from elastoplast.bounds.bracket import combine
    from elastoplast.references.certified import u_bracket_of
    from elastoplast.bounds.upper import upper_bound
    import elastoplast.bounds.equilibrium.bound as eq
    from elastoplast.limits import MEMORY_ENV
    from elastoplast.errors import InputError

    data = small_cylinder()
    data["mesh"]["divisions"] = [10, 5]  # 100 triangles: 4.5 MB for one program, 9 MB in a row
    problem = ep.problem_from_dict(data, base_dir=PROBLEMS)
    monkeypatch.setenv(MEMORY_ENV, "6M")
    assert lower_bound_budget(2, AdaptOptions())[0] == "the memory available to the lower bound"
    with pytest.raises(InputError) as info:
        adapt(problem, AdaptOptions(rtol=0.01, bracket="never", compare_uniform=False))
    assert info.value.field == "mesh" and "memory" in info.value.message
    monkeypatch.delenv(MEMORY_ENV)
    real, calls = eq.solve_lower_bound, []

    def refuse_the_second(disc, options=None):
        calls.append(disc.n_elements)
        if len(calls) == 2:
            raise InputError("mesh", "the equilibrium-element lower bound needs about 9 GiB, more than the 1 GiB available")
        return real(disc, options)

    monkeypatch.setattr(eq, "solve_lower_bound", refuse_the_second)
    run = adapt(problem, AdaptOptions(rtol=1e-6, bracket="never", compare_uniform=False))
    assert len(run.steps) == 1 and len(run.meshes) == 1 and "refused the next mesh" in run.reason
    assert run.disc.n_elements == 100 and run.bounds.bounds_certified
    calls.clear()
    calls.append(0)  # the next call is refused: the bracket's first program
    disc = build(data)
    b = combine(upper_bound(disc, ep.solve(disc, "newton")), real(disc))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        lo, hi, _, certified = u_bracket_of(disc, b, 0.04)
    assert math.isnan(lo) and math.isnan(hi) and not certified
    assert any("no U bracket" in str(w.message) for w in caught)
