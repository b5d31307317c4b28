"""Hostile inputs, fourth round (issue 39): one test per class of failure.

Plug-ins cannot change the problem they are judged on nor end the program; a path's
step file is checked against that step; figures at round-off scale do not contradict
the status; flags that do nothing are noted.
"""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
import time
import textwrap
from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.cli.main import main
from elastoplast.io.loading_path import path_status
from elastoplast.solvers.plugins import PluginError

ROOT = Path(__file__).resolve().parents[1]
SMALL = ROOT / "examples" / "plugin_method" / "small_2d.toml"


@pytest.fixture(scope="module")
def disc():
    return ep.discretize(ep.load_problem(SMALL))


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """Write a module ``name`` of ``source`` on sys.path; returns its folder."""
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.syspath_prepend(str(SMALL.parent))  # the example file's own [solver] method

    def write(name: str, source: str) -> Path:
        (tmp_path / f"{name}.py").write_text(textwrap.dedent(source))
        return tmp_path

    return write


def one_error_line(capsys) -> str:
    """The one ``error:`` line on stderr (warnings about the input may precede it)."""
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("warning:")]
    assert len(err) == 1, err
    return err[0]


def test_a_method_cannot_change_the_problem_it_is_judged_on(disc, plugin):
    """Every array of the Discretization is read-only, also after pickling; a method
    that swaps an operator on the object it was given (object.__setattr__ passes the
    frozen dataclass) solved another problem, and the certificate, judging against the
    problem as given, says so."""
    for d in (disc, pickle.loads(pickle.dumps(disc))):
        for a in (d.free, d.fixed, d.contact_nodes, d.psi, d.volumes, d.N.data, d.N.indices, d.B.data,
                  d.B.indptr):
            with pytest.raises(ValueError, match="read-only"):
                a[...] = 0
    plugin("ep_edits", """
        import elastoplast as ep

        def in_place(disc, options):
            disc.N.data *= 3.0
            return ep.solve(disc, "newton")

        def swapped(disc, options):
            object.__setattr__(disc, "psi", 3.0 * disc.psi)  # an obstacle three times as far
            sol = ep.solve(disc, "newton")
            return sol.u, sol.U
    """)
    with pytest.raises(PluginError, match="ep_edits:in_place.*read-only"):
        ep.solve(disc, "ep_edits:in_place")
    swapped = ep.solve(disc, "ep_edits:swapped")
    # the edited problem's own answer: converged there, so the check has a real alternative
    edited = ep.solve(ep.Discretization(**{**disc.__dict__, "psi": 3.0 * disc.psi}), "newton")
    assert edited.status is ep.Status.CONVERGED and not np.allclose(edited.u, ep.solve(disc, "newton").u)
    assert swapped.status is not ep.Status.CONVERGED
    assert np.array_equal(disc.psi, pickle.loads(pickle.dumps(disc)).psi)


def test_plugins_that_exit_or_answer_in_a_wrong_shape(disc, plugin, capsys, tmp_path):
    """sys.exit() at import is bad input (exit 2), inside run a plug-in error (exit 3), each
    in one line; a transposed u is refused, not reshaped; a wrong type is one line."""
    plugin("ep_exits", """
        import sys
        import elastoplast as ep

        def run(disc, options):
            sys.exit(0)

        def transposed(disc, options):
            sol = ep.solve(disc, "newton")
            return sol.u.T.copy(), sol.U

        def matrix_U(disc, options):
            sol = ep.solve(disc, "newton")
            return sol.u, sol.u
    """)
    plugin("ep_exits_at_import", "import sys\nsys.exit(0)\n")
    out = str(tmp_path / "out")
    assert main(["solve", str(SMALL), "--method", "ep_exits:run", "--out", out, "--quiet"]) == 3
    assert "sys.exit(0) was called" in one_error_line(capsys)
    assert main(["solve", str(SMALL), "--method", "ep_exits_at_import:run", "--out", out, "--quiet"]) == 2
    assert "sys.exit(0) was called" in one_error_line(capsys)
    assert main(["options", "ep_exits_at_import:run"]) == 2
    one_error_line(capsys)
    if disc.mesh.n_nodes != disc.dim:  # a square u would be ambiguous; small_2d's is not
        with pytest.raises(PluginError, match=r"expected shape .* got \(2, "):
            ep.solve(disc, "ep_exits:transposed")
    assert main(["solve", str(SMALL), "--method", "ep_exits:matrix_U", "--out", out, "--quiet"]) == 3
    line = one_error_line(capsys)
    assert "ep_exits:matrix_U" in line and "shape" in line


def test_check_on_a_path_step_file_reads_that_steps_U(tmp_path, capsys):
    """A path's solution_001.vtu holds step 1's u; its U is step 1's entry of the summary's
    "path", not the last step's. Step 1 of a path from rest is Hencky's problem at its
    force (backward Euler from a zero state, docs/evolution.md), so the same problem with
    ``load.force`` = that force certifies it; the last step's file against step 1's force
    is still refused."""
    from conftest import PROBLEMS
    from test_cli import write_toml

    data = ep.read_toml(PROBLEMS / "indentation_path_2d.toml")
    data["mesh"]["divisions"] = [16, 8]
    data["load"] = {"path": [1000.0, 3000.0]}
    path_file = write_toml(tmp_path / "path.toml", data)
    out = tmp_path / "out"
    assert main(["solve", str(path_file), "--method", "newton", "--out", str(out), "--quiet"]) == 0
    data["load"] = {"force": 1000.0}
    first = write_toml(tmp_path / "first.toml", data)
    capsys.readouterr()
    assert main(["check", str(first), str(out / "solution_001.vtu")]) == 0, capsys.readouterr().err
    assert main(["check", str(first), str(out / "solution_002.vtu")]) == 1


def test_the_duality_gap_of_round_off_energies_is_not_a_figure(disc, tmp_path):
    """Elastic answers scale exactly with the force (U and u linear in F while no node
    leaves or joins the contact): at F = 1e-9 and 1e-12 the values of (S) and (D) are
    below the rounding of their terms, and the gap is NaN (summary.json null, printed
    n/a) instead of 1e-2 or 1 beside a converged status; at a force where they are not
    round-off the gap is still a number, and small."""
    for force in (1e-9, 1e-12):
        sol = ep.solve(disc.with_force(force), "newton")
        assert sol.status is ep.Status.CONVERGED and np.isnan(sol.duality_gap)
    sol = ep.solve(disc.with_force(1e-3), "newton")
    assert sol.duality_gap < 1e-6
    full = ep.solve(disc, "newton")
    assert full.duality_gap < 1e-10


def test_a_mirrored_half_is_reoriented_and_a_fold_refused(tmp_path, capsys):
    """The left half of a square's triangles listed clockwise (as mirroring a half model
    and joining it produces) is the same geometry: read with a warning, it solves to
    the U of the square listed one way (the same elements, so the same discrete
    problem). Moving an interior node past its neighbour folds the mesh: refused."""
    from test_inputs import grid, grid_sides, grid_triangles, solve_cli, square_problem, write_gmsh
    from test_cli import write_toml

    points, tris = grid(8, 4), grid_triangles(8, 4)
    left = points[tris].mean(axis=1)[:, 0] < 1.0
    mirrored = tris.copy()
    mirrored[left, :2] = mirrored[left, 1::-1]
    problem = write_toml(tmp_path / "p.toml", square_problem("m.msh"))
    Us = []
    for cells in (tris, mirrored):
        write_gmsh(tmp_path / "m.msh", points, [("triangle", cells, 100)] + grid_sides(8, 4))
        assert solve_cli(tmp_path, problem) == 0
        Us.append(json.loads((tmp_path / "out" / "summary.json").read_text())["U"])
        err = capsys.readouterr().err
    assert f"{int(left.sum())} of {len(tris)} elements were listed with the opposite orientation" in err
    assert Us[1] == pytest.approx(Us[0], rel=1e-12)
    folded = points.copy()
    folded[9 + 3] = [1.8, 0.25]  # node (3, 1) at x = 0.75 moved past node (7, 1) at x = 1.75
    write_gmsh(tmp_path / "m.msh", folded, [("triangle", tris, 100)] + grid_sides(8, 4))
    assert solve_cli(tmp_path, problem) == 2
    assert "error: mesh.file: the mesh folds over itself" in capsys.readouterr().err


def test_descent_where_it_does_nothing(tmp_path, capsys):
    """--descent steers the local lower bound only: with hardening = 0 (the global
    program is the only lower bound) or --lower global it is refused naming the flag,
    before any solve; where auto chooses the global program it is noted."""
    from test_cli import write_toml

    data = ep.read_toml(SMALL)
    data.pop("solver", None)
    small = write_toml(tmp_path / "h.toml", data)
    out = str(tmp_path / "out")
    assert main(["bounds", str(small), "--descent", "3", "--lower", "global", "--out", out, "--quiet"]) == 2
    assert one_error_line(capsys).startswith("error: --descent: does nothing with --lower global")
    data["material"]["hardening"] = 0.0
    perfect = write_toml(tmp_path / "p.toml", data)
    assert main(["bounds", str(perfect), "--descent", "3", "--out", out, "--quiet"]) == 2
    assert one_error_line(capsys).startswith("error: --descent: does nothing with hardening = 0")
    assert main(["adapt", str(small), "--descent", "3", "--lower", "global", "--out", out, "--quiet"]) == 2
    assert one_error_line(capsys).startswith("error: --descent: does nothing with --lower global")
    main(["bounds", str(small), "--descent", "3", "--out", out, "--quiet", "--no-bracket"])
    assert "warning: --descent 3 does nothing here" in capsys.readouterr().err


def test_a_file_too_large_for_the_limit_is_exit_2_naming_out(tmp_path):
    """A file-size limit (RLIMIT_FSIZE, as a full or capped disk acts: EFBIG) met while
    solve writes its files is the place written to, as for export: exit 2, one line
    naming --out, and the folder not left half-written."""
    out = tmp_path / "out"
    code = ("import resource, sys; from elastoplast.cli.main import main; "
            "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096)); "
            f"sys.exit(main(['solve', {str(SMALL)!r}, '--method', 'newton', '--out', {str(out)!r}, '--quiet']))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(SMALL.parent)])})
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --out: cannot write"), lines
    assert not out.exists()


def test_numpy_warnings_reach_the_user_once_per_kind(plugin, tmp_path, capsys):
    """An answer of 1e200 overflows in the certificate's arithmetic: each kind of numpy
    floating-point warning is one marked line, never repeated, and the status (the answer
    holds non-finite values) decides the exit code."""
    plugin("ep_huge", """
        import elastoplast as ep

        def run(disc, options):
            sol = ep.solve(disc, "newton")
            return 1e200 * sol.u, 1e200 * sol.U
    """)
    assert main(["solve", str(SMALL), "--method", "ep_huge:run", "--out", str(tmp_path / "out"), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    said = [line for line in err if "encountered in" in line]
    assert said and len(said) == len(set(said)), err
    assert all(line.startswith("warning: floating-point arithmetic: ") for line in said), said
    assert err[-1].startswith("not converged: ")


def test_time_limit_bounds_a_whole_path(disc, tmp_path, capsys):
    """--time-limit on a path is the whole run's: a path of many steps stops once it is
    spent (status time_limit, exit 1, the steps run kept), not after each step's own
    limit. The steps of small_2d take milliseconds each: 400 of them outlast 0.2 s."""
    forces = [disc.force * (1 + (i % 2)) / 2 for i in range(400)]
    start = time.perf_counter()
    result = ep.solve_path(disc, forces, "newton", time_limit=0.2)
    took = time.perf_counter() - start
    assert not result.converged and 0 < len(result.steps) < len(forces)
    assert all(s.converged for s in result.steps[:-1])
    last = result.steps[-1].solution.status
    # spent between steps (the path says so) or inside the last one (its solver says so)
    assert ("time limit of 0.2 s" in result.stopped) if last is ep.Status.CONVERGED else last is ep.Status.TIME_LIMIT
    assert path_status(result)[0] is ep.Status.TIME_LIMIT
    assert took < 0.2 + 5 * max(s.solution.time_s for s in result.steps) + 1.0


def test_bounds_without_a_method_picks_one_that_can_run(tmp_path, capsys, monkeypatch):
    """bounds with no method named on a mesh beyond the conic reference's size solves
    by newton and says so (the 227,000-tetrahedra case, with the size limit lowered
    below small_2d's 144 triangles); a method the user names is still refused there."""
    from elastoplast.solvers.registry import CONIC_MAX_ELEMENTS
    from test_cli import write_toml

    monkeypatch.setitem(CONIC_MAX_ELEMENTS, 2, 100)
    data = ep.read_toml(SMALL)
    data.pop("solver", None)
    small = write_toml(tmp_path / "h.toml", data)
    out = tmp_path / "out"
    assert main(["bounds", str(small), "--no-bracket", "--out", str(out), "--quiet"]) == 0
    assert "note: 144 elements is beyond the conic reference's 100 in 2D: the P1 solution by newton" in \
        capsys.readouterr().err
    assert json.loads((out / "summary.json").read_text())["method"] == "newton"
    assert main(["bounds", str(small), "--method", "conic", "--no-bracket", "--out", str(out), "--quiet"]) == 2
    assert "beyond what the conic reference can finish" in one_error_line(capsys)
