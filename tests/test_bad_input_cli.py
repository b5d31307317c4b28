"""Bad input, third round, the command line: bounded messages, the status words the
README promises, no NaN printed, a friendlier command line, user paths that the file
system refuses, and campaign input that used to vanish. Each test gives the exact
input of the report and asserts the exit code and what the message names."""

from __future__ import annotations

import dataclasses
import importlib.metadata
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.bounds.lower import LowerBoundOptions, check_lower_bound_size
from elastoplast.studies.campaign import load_campaign
from elastoplast.cli.main import build_parser, main
from elastoplast.errors import FIELD_WIDTH, MESSAGE_WIDTH, InputError, elide
from elastoplast.io.store import Store
from elastoplast.solvers.registry import METHODS

from conftest import PROBLEMS, ROOT, build
from test_cli import small_cylinder, write_toml

#: the longest error line: "error: " + field + ": " + message
LONGEST_LINE = len("error: ") + FIELD_WIDTH + len(": ") + MESSAGE_WIDTH
LONG_NAME = "n" * 100_000
LONG_FLAG = "m" * 50_000
#: a path component longer than any file system's NAME_MAX (255)
LONG_PATH = "p" * 300


def run(capsys, *argv) -> tuple[int, str, list[str]]:
    """``(exit code, stdout, stderr lines)`` of the command line."""
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err.strip().splitlines()


@pytest.fixture
def problem_file(tmp_path):
    return write_toml(tmp_path / "base.toml", small_cylinder())


def with_text(path: Path, extra: str) -> Path:
    """The small cylinder's problem file with TOML lines appended."""
    write_toml(path, small_cylinder())
    path.write_text(path.read_text() + extra)
    return path


def empty_store(path: Path) -> Path:
    """A campaign store holding no case (its index only)."""
    with Store(path).writer():
        pass
    return path


# ---------------------------------------------------------------------------
# 1. unbounded messages
# ---------------------------------------------------------------------------


def test_elide_keeps_start_and_end_and_the_width():
    text = "start-" + "x" * 10_000 + "-end"
    cut = elide(text, 100)
    assert len(cut) <= 100 and cut.startswith("start-") and cut.endswith("-end") and "..." in cut
    assert elide("short", 100) == "short"
    err = InputError("load." + LONG_NAME, "unknown key " + LONG_NAME + " (allowed: force)")
    assert len(err.field) <= FIELD_WIDTH and err.field.startswith("load.n")
    assert len(err.message) <= MESSAGE_WIDTH and err.message.endswith("(allowed: force)")


@pytest.mark.parametrize("extra,field", [
    (f'\n[boundary]\nclamped = ["xmin", "xmax", "top"]\ncontact = ["{LONG_NAME}"]\n', "boundary.contact"),
    (f"\n[{LONG_NAME}]\nx = 1\n", "problem.nnnn"),
    (f'\n[boundary]\nclamped = ["xmin", "xmax", "top"]\ncontact = ["contact"]\n[boundary.fix_component]\n'
     f'{LONG_NAME} = ["xmin"]\n', "boundary.fix_component.nnnn"),
    (f'\n[solver]\nmethod = "{LONG_NAME}"\n', "solver.method"),
    (f"\n[solver]\n{LONG_NAME} = 1\n", "solver.nnnn"),
])
def test_a_long_name_in_a_problem_file_gives_a_short_line(tmp_path, capsys, extra, field):
    code, _, err = run(capsys, "solve", with_text(tmp_path / "p.toml", extra), "--out", tmp_path / "o", "--quiet")
    assert code == 2 and len(err) == 1 and err[0].startswith(f"error: {field}"), err[0][:200]
    assert len(err[0]) <= LONGEST_LINE


def test_a_long_key_in_load_gives_a_short_line(tmp_path, capsys):
    data = small_cylinder()
    data["load"][LONG_NAME] = 1.0
    code, _, err = run(capsys, "solve", write_toml(tmp_path / "p.toml", data), "--out", tmp_path / "o", "--quiet")
    assert code == 2 and err[-1].startswith("error: load.nnnn") and len(err[-1]) <= LONGEST_LINE, err[-1][:200]


@pytest.mark.parametrize("flags,field", [
    (["--method", LONG_FLAG], "--method"),
    (["--" + LONG_FLAG], "arguments"),
    (["--option", f"{LONG_FLAG}=1"], "--option mmmm"),
    (["--option", LONG_FLAG], "--option"),
    (["--tol", "b" + LONG_FLAG], "arguments"),
])
def test_a_long_flag_gives_a_short_line(problem_file, tmp_path, capsys, flags, field):
    code, _, err = run(capsys, "solve", problem_file, "--out", tmp_path / "o", "--quiet", *flags)
    assert code == 2 and err[-1].startswith(f"error: {field}") and len(err[-1]) <= LONGEST_LINE, err[-1][:200]


def test_a_long_reference_method_gives_a_short_line(tmp_path, capsys):
    store = empty_store(tmp_path / "store")
    code, _, err = run(capsys, "compare", store, "--method", "conic", "--reference-method", LONG_FLAG, "--quiet")
    assert code == 2 and err[-1].startswith("error: --reference-method:") and len(err[-1]) <= LONGEST_LINE, err[-1][:200]


def test_a_long_sweep_axis_and_campaign_name_are_bounded(problem_file, tmp_path, capsys):
    axis = tmp_path / "axis.toml"
    axis.write_text(f'[campaign]\nproblem = "{problem_file}"\n[sweep]\n"material.{LONG_NAME}" = [1.0]\n')
    code, _, err = run(capsys, "campaign", axis, "--out", tmp_path / "s", "--quiet")
    assert code == 2 and err[-1].startswith("error: sweep.material.nnnn") and len(err[-1]) <= LONGEST_LINE, err[-1][:200]
    named = tmp_path / "named.toml"
    named.write_text(f'[campaign]\nname = "{LONG_NAME}"\nproblem = "{problem_file}"\n')
    code, out, err = run(capsys, "campaign", named, "--out", tmp_path / "s", "--quiet")
    assert code == 2 and err[-1].startswith("error: campaign.name:") and out == "", err[-1][:200]
    assert len(err[-1]) <= LONGEST_LINE and not (tmp_path / "s").exists()


# ---------------------------------------------------------------------------
# 2. the status words docs/commands.md promises
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["conic-cvxpy", "conic-displacement"])
@pytest.mark.parametrize("flags,status", [(["--time-limit", "1e-9"], "time_limit"),
                                          (["--max-iter", "1"], "max_iterations")])
def test_cvxpy_limits_end_with_the_promised_status(problem_file, tmp_path, capsys, method, flags, status):
    code, _, _ = run(capsys, "solve", problem_file, "--method", method, "--out", tmp_path / "o", "--quiet", *flags)
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert code == 1 and summary["status"] == status, summary["message"]


def test_cvxpy_failure_advises_in_command_line_terms(monkeypatch):
    """CVXPY's own advice ("solve with verbose=True") becomes one that works on the
    command line and from Python."""
    import cvxpy as cp

    def failing(self, *args, **kwargs):
        raise cp.error.SolverError("Solver 'CLARABEL' failed. Try another solver, or solve with verbose=True for "
                                   "more information.")

    monkeypatch.setattr(cp.Problem, "solve", failing)
    sol = ep.solve(build(small_cylinder()), "conic-cvxpy")
    assert sol.status is ep.Status.FAILED
    assert "--option verbose=true" in sol.message and "verbose=True from Python" in sol.message
    assert "solve with verbose=True" not in sol.message


# ---------------------------------------------------------------------------
# 3. no NaN printed
# ---------------------------------------------------------------------------


def test_a_non_finite_figure_prints_as_n_a(problem_file, tmp_path, capsys, monkeypatch):
    """The report's input (uzawa-fast, ALG2, penalty = 1e-300) ended diverged with NaN
    pressures and printed "max contact pressure = nan"; such a penalty is now refused
    as input, so a diverged answer with the same NaN is made here from a real one."""
    real = METHODS["uzawa-fast"]

    def diverging(disc, options):
        sol = real.run(disc, options)
        return dataclasses.replace(sol, status=ep.Status.DIVERGED, U=float("nan"),
                                   contact_pressure=np.full_like(sol.contact_pressure, np.nan))

    monkeypatch.setitem(METHODS, "uzawa-fast", dataclasses.replace(real, run=diverging))
    code, out, _ = run(capsys, "solve", problem_file, "--method", "uzawa-fast", "--max-iter", "5",
                       "--out", tmp_path / "o", "--quiet")
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert code == 1 and summary["max_contact_pressure"] is None  # not finite: null in strict JSON
    assert "U = n/a" in out and "max contact pressure = n/a" in out and not re.search(r"\bnan\b", out, re.I), out


# ---------------------------------------------------------------------------
# 4. a friendlier command line
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("flag", ["--version", "-V"])
def test_version_prints_the_installed_version(capsys, flag):
    code, out, _ = run(capsys, flag)
    assert code == 0 and out == f"elastoplast {importlib.metadata.version('elastoplast')}\n"


def _shown(value, kind) -> str:
    """How a default or a bound is written in TOML (what --option NAME= takes)."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return str(int(value)) if kind is int else f"{value:g}"


@pytest.mark.parametrize("method", sorted(METHODS))
def test_options_lists_each_option_with_default_and_range(capsys, method):
    code, out, _ = run(capsys, "options", method)
    assert code == 0
    cls = METHODS[method].options
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    lines = {line.split()[0]: line for line in out.splitlines() if line.startswith("  ")}
    for name, spec in cls.specs().items():
        line = lines[name]
        assert f" {_shown(defaults[name], spec.kind)} " in line, line
        for bound in (spec.lo, spec.hi):
            if bound is not None:
                assert _shown(bound, spec.kind) in line, line
        for choice in spec.choices or ():
            assert f'"{choice}"' in line, line
        assert spec.doc in line


def test_every_subcommand_is_in_the_readme():
    readme = (ROOT / "README.md").read_text()
    sub = next(a for a in build_parser()._subparsers._group_actions)
    for command in sub.choices:
        assert re.search(rf"elastoplast {command}\b", readme), command


def _recording(monkeypatch, name: str) -> list:
    """Replace method ``name`` by one that records its options and then runs it."""
    seen, real = [], METHODS[name]

    def record(disc, options):
        seen.append(options)
        return real.run(disc, options)

    monkeypatch.setitem(METHODS, name, dataclasses.replace(real, run=record))
    return seen


def test_method_flag_drops_the_files_options_it_does_not_have(tmp_path, capsys, monkeypatch):
    """`[solver] rho = 1e-6` with `--method newton` was refused (the table was checked
    against the file's method); now rho is dropped with a note, and applies where the
    chosen method has it, the flags winning."""
    problem = with_text(tmp_path / "p.toml", "\n[solver]\nrho = 1e-6\n")
    code, _, err = run(capsys, "solve", problem, "--method", "newton", "--out", tmp_path / "a", "--quiet")
    assert code == 0 and "note: solver.rho: not an option of newton (--method), ignored" in err, err
    seen = _recording(monkeypatch, "uzawa")
    run(capsys, "solve", problem, "--method", "uzawa", "--max-iter", "2", "--out", tmp_path / "b", "--quiet")
    run(capsys, "solve", problem, "--method", "uzawa", "--max-iter", "2", "--rho", "2e-6", "--out", tmp_path / "c",
        "--quiet")
    assert [o.rho for o in seen] == [1e-6, 2e-6]


def test_limit_reads_no_solver_table_and_adapt_warns_first(tmp_path, capsys):
    data = small_cylinder()
    data["mesh"]["divisions"] = [10, 5]
    data["solver"] = {"rho": 1e-6}
    h0 = dict(data, material={**data["material"], "hardening": 0.0})
    code, _, err = run(capsys, "limit", write_toml(tmp_path / "h0.toml", h0), "--out", tmp_path / "l", "--quiet")
    assert code in (0, 1) and not any(line.startswith("error") for line in err), err
    code, _, err = run(capsys, "adapt", write_toml(tmp_path / "a.toml", data), "--rtol", "0.5", "--no-uniform",
                       "--out", tmp_path / "a", "--quiet")
    assert code == 0 and any(line.startswith("warning: solver.rho: not used by adapt") for line in err), err
    data["solver"] = {"method": "conic-cvxpy"}  # a method, but not one adapt runs: the file's key is named
    code, _, err = run(capsys, "adapt", write_toml(tmp_path / "b.toml", data), "--out", tmp_path / "b", "--quiet")
    assert code == 2 and err[-1].startswith("error: solver.method:"), err


@pytest.mark.parametrize("argv,field", [
    (["campaign", PROBLEMS / "campaign_2d.toml", "--workers", "0"], "--workers"),
    (["campaign", PROBLEMS / "campaign_2d.toml", "--scheduler", "not a url"], "--scheduler"),
    (["compare", "missing-store", "--method", "conic"], "STORE"),
])
def test_campaign_and_compare_name_their_flags(tmp_path, capsys, argv, field):
    code, _, err = run(capsys, *argv, "--out", tmp_path / "o", "--quiet")
    assert code == 2 and err[-1].startswith(f"error: {field}:"), err[-1]
    assert not (tmp_path / "o").exists()


def test_lower_bound_size_refusal_advises_what_the_command_line_can_do(problem_file, tmp_path, capsys):
    disc = build(small_cylinder())
    with pytest.raises(InputError) as info:
        check_lower_bound_size(disc, LowerBoundOptions(max_elements=disc.n_elements - 1))
    assert "coarsen the mesh" in info.value.message and "elastoplast adapt" in info.value.message
    assert "LowerBoundOptions(max_elements=" in info.value.message
    # what it no longer advises: the command line has no such option
    code, _, err = run(capsys, "bounds", problem_file, "--option", "max_elements=30000", "--out", tmp_path / "o")
    assert code == 2 and err[-1].startswith("error: --option max_elements:"), err[-1]


# ---------------------------------------------------------------------------
# 5. paths the file system refuses are bad input, not internal errors
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("command", ["solve", "bounds", "limit", "adapt"])
def test_a_long_out_names_out(problem_file, capsys, command):
    code, _, err = run(capsys, command, problem_file, "--out", LONG_PATH, "--quiet")
    assert code == 2 and err[-1].startswith("error: --out:") and "too long" in err[-1], err[-1]
    assert len(err[-1]) <= LONGEST_LINE


def test_long_store_and_campaign_paths_name_their_arguments(tmp_path, capsys):
    code, _, err = run(capsys, "campaign", PROBLEMS / "campaign_2d.toml", "--out", LONG_PATH, "--quiet")
    assert code == 2 and err[-1].startswith("error: --out:"), err[-1]
    code, _, err = run(capsys, "compare", LONG_PATH, "--method", "conic", "--quiet")
    assert code == 2 and err[-1].startswith("error: STORE:"), err[-1]
    store = empty_store(tmp_path / "store")
    code, _, err = run(capsys, "compare", store, "--method", "conic", "--out", LONG_PATH, "--quiet")
    assert code == 2 and err[-1].startswith("error: --out:"), err[-1]
    code, _, err = run(capsys, "campaign", LONG_PATH + ".toml", "--out", tmp_path / "s", "--quiet")
    assert code == 2 and err[-1].startswith("error: campaign:"), err[-1]
    (tmp_path / "sub").mkdir()
    for problem, words in ((LONG_PATH, "too long"), ("sub", "is a directory")):
        path = tmp_path / "c.toml"
        path.write_text(f'[campaign]\nproblem = "{problem}"\n')
        code, _, err = run(capsys, "campaign", path, "--out", tmp_path / "s", "--quiet")
        assert code == 2 and err[-1].startswith("error: campaign.problem:") and words in err[-1], err[-1]
    assert not (tmp_path / "s").exists()


def test_a_scheduler_without_a_port_is_refused_and_leaves_no_store(tmp_path, capsys):
    code, _, err = run(capsys, "campaign", PROBLEMS / "campaign_2d.toml", "--out", tmp_path / "s", "--scheduler",
                       "foo", "--quiet")
    assert code == 2 and err[-1].startswith("error: --scheduler:") and "port" in err[-1], err[-1]
    assert not (tmp_path / "s").exists()


# ---------------------------------------------------------------------------
# 6. campaign input that used to vanish
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("sweep,axis", [
    ('"material.E" = [2e5, 2.1e5]\nmaterial.E = [1e5]', "material.E"),
    ('method = ["conic"]\n"solver.method" = ["newton"]', "solver.method"),
])
def test_an_axis_spelled_twice_is_refused(problem_file, tmp_path, capsys, sweep, axis):
    path = tmp_path / "c.toml"
    path.write_text(f'[campaign]\nproblem = "{problem_file}"\n[sweep]\n{sweep}\n')
    code, _, err = run(capsys, "campaign", path, "--out", tmp_path / "s", "--quiet")
    assert code == 2 and err[-1].startswith(f"error: sweep.{axis}: given twice"), err[-1]


def test_relative_mesh_files_are_read_from_the_file_they_are_written_in(tmp_path):
    """The base problem's `[mesh] file` is relative to the problem file; an inline one
    and a `mesh.file` axis to the campaign file."""
    sub = tmp_path / "sub"
    sub.mkdir()
    shutil.copy(PROBLEMS / "punch_2d.msh", sub / "punch_2d.msh")
    shutil.copy(PROBLEMS / "punch_2d_gmsh.toml", sub / "p.toml")
    assert ep.read_toml(sub / "p.toml")["mesh"]["file"] == "punch_2d.msh"  # relative to sub/
    shutil.copy(PROBLEMS / "punch_2d.msh", tmp_path / "beside.msh")
    campaign = tmp_path / "c.toml"
    campaign.write_text('[campaign]\nproblem = "sub/p.toml"\n[sweep]\n"load.force" = [1000.0]\n')
    n_nodes = ep.load_problem(sub / "p.toml").mesh.n_nodes
    assert load_campaign(campaign).cases[0].input.arrays["points"].shape[0] == n_nodes
    inline = tmp_path / "inline.toml"
    inline.write_text(campaign.read_text() + '[mesh]\nfile = "beside.msh"\n')
    assert len(load_campaign(inline).cases) == 1
    axis = tmp_path / "axis.toml"
    axis.write_text(campaign.read_text() + '"mesh.file" = ["beside.msh"]\n')
    assert len(load_campaign(axis).cases) == 1
    (sub / "punch_2d.msh").unlink()  # the base problem's mesh is missing: named as its own field
    with pytest.raises(InputError) as info:
        load_campaign(campaign)
    assert info.value.field == "mesh.file", info.value


@pytest.mark.parametrize("command", ["solve", "campaign"])
def test_a_dotdot_through_a_missing_folder_never_replaces_a_foreign_folder(problem_file, tmp_path, capsys,
                                                                             monkeypatch, command):
    """Found in the third pass: `--out nosuch/../victim` was judged as a new folder (nosuch did not
    exist), then resolved to victim once nosuch was created, and victim with the user's files was
    replaced (solve) or filled with a store (campaign); a refused campaign then removed it whole.
    The path is now resolved before it is judged: refused, and victim left as it was."""
    monkeypatch.chdir(tmp_path)
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "thesis.tex").write_text("precious")
    target = "nosuch/../victim"
    if command == "solve":
        code, _, err = run(capsys, "solve", problem_file, "--out", target, "--quiet")
    else:
        code, _, err = run(capsys, "campaign", PROBLEMS / "campaign_2d.toml", "--out", target, "--quiet",
                            "--workers", "1")
    assert code == 2 and err[-1].startswith("error: --out:"), err
    assert sorted(p.name for p in victim.iterdir()) == ["thesis.tex"]
    assert (victim / "thesis.tex").read_text() == "precious"
    code, _, err = run(capsys, "solve", problem_file, "--out", "sub/../.", "--quiet")
    assert code == 2 and "working directory" in err[-1], err
    assert not (tmp_path / "sub").exists()
