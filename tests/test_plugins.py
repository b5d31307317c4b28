"""Methods from outside the package (docs/methods.md, "Methods from outside").

The example plug-in ``examples/plugin_method/jacobi_uzawa.py`` runs through
``ep.solve``, ``elastoplast solve``, a campaign and ``compare``; the package, not the
plug-in, decides whether an answer converged; loading errors are input errors in one
line; an entry point of the group ``elastoplast.methods`` is found by its name.
Entry points are declared the way an installed distribution declares them: a
``*.dist-info`` folder on ``sys.path`` read by ``importlib.metadata``.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest

import elastoplast as ep
from elastoplast.studies.campaign import load_campaign, run_campaign
from elastoplast.studies.compare import compare
from elastoplast.cli.main import main
from elastoplast.io.store import Store
from elastoplast.solvers.plugins import GROUP, PluginError
from elastoplast.solvers.registry import METHODS, get_method, method_options

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "plugin_method"
SMALL = EXAMPLE / "small_2d.toml"
#: enough iterations for the plain function on small_2d.toml (it needs a few thousand)
ITERATIONS = 20_000


@pytest.fixture
def example(monkeypatch):
    """The example's folder on sys.path (this process) and PYTHONPATH (processes started now)."""
    monkeypatch.syspath_prepend(str(EXAMPLE))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(EXAMPLE), os.environ.get("PYTHONPATH")])))


@pytest.fixture(scope="module")
def disc():
    return ep.discretize(ep.load_problem(SMALL))


@pytest.fixture(scope="module")
def reference(disc):
    return ep.solve(disc, "newton")


def write_module(folder: Path, name: str, source: str) -> None:
    (folder / f"{name}.py").write_text(textwrap.dedent(source))


def declare_entry_points(folder: Path, dist: str, entries: dict[str, str]) -> None:
    """An installed distribution ``dist`` declaring ``entries`` in the group, as pip leaves it."""
    info = folder / f"{dist.replace('-', '_')}-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n")
    lines = "".join(f"{name} = {value}\n" for name, value in entries.items())
    (info / "entry_points.txt").write_text(f"[{GROUP}]\n{lines}")


def one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_example_through_ep_solve(example, disc, reference):
    for name, values in (("jacobi_uzawa:run", {"max_iter": ITERATIONS}), ("jacobi_uzawa:METHOD", {})):
        sol = ep.solve(disc, name, **values)
        assert sol.method == name and sol.status is ep.Status.CONVERGED, sol.message
        assert sol.kkt.worst <= 1e-6 and sol.timings["total"] > 0
        assert abs(sol.U - reference.U) <= 1e-5 * abs(reference.U)
        # its stresses are the return mapping of its u: the constitutive residual is zero
        assert sol.kkt.constitutive == 0.0
    # the options: the base class for the function, the Method's own class, checked alike
    assert type(method_options("jacobi_uzawa:run")) is ep.SolverOptions
    assert method_options("jacobi_uzawa:METHOD").max_iter == 100_000
    with pytest.raises(ep.InputError, match=r"^rho: method 'jacobi_uzawa:run' has no option 'rho'"):
        ep.solve(disc, "jacobi_uzawa:run", rho=1e-6)
    with pytest.raises(ep.InputError, match=r"^check_every: must be an integer in \[1, 10000\]"):
        ep.solve(disc, "jacobi_uzawa:METHOD", check_every=0)
    # stopped early, the answer is judged by the certificate: not converged, and said why
    short = ep.solve(disc, "jacobi_uzawa:run", max_iter=50)
    assert short.status is ep.Status.FAILED and "is above tol 1e-06" in short.message


def test_example_through_the_command_line(example, tmp_path, capsys):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "elastoplast", "solve", str(SMALL), "--method", "jacobi_uzawa:run", "--max-iter",
           str(ITERATIONS), "--out", str(out), "--quiet"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["method"] == "jacobi_uzawa:run" and summary["status"] == "converged" and summary["kkt_worst"] <= 1e-6
    # the file's own [solver] method = "jacobi_uzawa:METHOD", in this process
    assert main(["solve", str(SMALL), "--out", str(tmp_path / "again"), "--quiet"]) == 0
    assert json.loads((tmp_path / "again" / "summary.json").read_text())["method"] == "jacobi_uzawa:METHOD"
    # too few iterations: exit 1, the certificate's verdict on stderr
    assert main(["solve", str(SMALL), "--method", "jacobi_uzawa:run", "--out", str(tmp_path / "short"),
                 "--quiet"]) == 1
    assert "the certificate's worst residual" in capsys.readouterr().err
    assert main(["options", "jacobi_uzawa:METHOD"]) == 0
    assert "check_every" in capsys.readouterr().out


def test_campaign_and_compare_with_the_example(example, tmp_path):
    """A campaign with the plug-in on its method axis, then ``compare`` of the plain
    function against the conic reference, on worker processes that import the
    example from PYTHONPATH."""
    from distributed import Client, LocalCluster

    path = tmp_path / "c.toml"
    path.write_text(f'[campaign]\nproblem = "{SMALL}"\n\n[sweep]\nmethod = ["conic", "jacobi_uzawa:METHOD"]\n')
    campaign = load_campaign(path)
    store = tmp_path / "store"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}, silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        run = run_campaign(campaign, store, client=client, progress=False)
        assert run.failed == {} and len(run.statuses) == 2
        rows = {r["method"]: r for r in Store(store).rows()}
        assert set(rows) == {"conic", "jacobi_uzawa:METHOD"}
        assert all(r["status"] == "converged" for r in rows.values())
        report = compare(store, "jacobi_uzawa:run", options={"max_iter": ITERATIONS}, reference_method="conic",
                         client=client, progress=False, out=tmp_path / "report")
    assert report.method == "jacobi_uzawa:run" and len(report.rows) == 1
    row = report.rows[0]
    assert row["status"] == "converged" and row["reference_method"] == "conic"
    assert row["U_rel"] < 1e-5 and row["sigma_rel"] < 1e-3
    assert (tmp_path / "report" / "report.md").read_text().startswith("# jacobi_uzawa:run against")


def test_the_certificate_decides_not_the_plugin(tmp_path, monkeypatch, disc, reference):
    """A Solution claiming CONVERGED (with a forged certificate) whose arrays are wrong
    comes out not converged; a right answer claiming less comes out converged."""
    monkeypatch.syspath_prepend(str(tmp_path))
    write_module(tmp_path, "ep_plugin_claims", """
        from dataclasses import replace
        import elastoplast as ep

        def wrong(disc, options):
            sol = ep.solve(disc, "newton")
            return replace(sol, U=1.01 * sol.U, status=ep.Status.CONVERGED)  # its kkt still says 1e-11

        def wrong_stopped(disc, options):
            return replace(wrong(disc, options), status=ep.Status.MAX_ITERATIONS, message="stopped")

        def modest(disc, options):
            return replace(ep.solve(disc, "newton"), status=ep.Status.MAX_ITERATIONS)

        def with_stresses(disc, options):
            sol = ep.solve(disc, "newton")
            return sol.u, sol.U, sol.sigma, sol.xi

        def fixed_moved(disc, options):
            sol = ep.solve(disc, "newton")
            u = sol.u.copy()
            u.reshape(-1)[disc.fixed[0]] = sol.U
            return u, sol.U
    """)
    wrong = ep.solve(disc, "ep_plugin_claims:wrong")
    assert wrong.status is ep.Status.FAILED and "is above tol 1e-06" in wrong.message
    assert wrong.kkt.worst > 1e-3 and wrong.method == "ep_plugin_claims:wrong"
    stopped = ep.solve(disc, "ep_plugin_claims:wrong_stopped")
    assert stopped.status is ep.Status.MAX_ITERATIONS and stopped.message.startswith("stopped; ")
    assert ep.solve(disc, "ep_plugin_claims:modest").status is ep.Status.CONVERGED
    four = ep.solve(disc, "ep_plugin_claims:with_stresses")
    assert four.converged and np.array_equal(four.sigma, reference.sigma) and four.iterations == 0
    moved = ep.solve(disc, "ep_plugin_claims:fixed_moved")
    assert moved.status is ep.Status.FAILED and "moves fixed components" in moved.message


@pytest.mark.parametrize("method, message", [
    ("no_such_module_xyz:run", "cannot import 'no_such_module_xyz' for method 'no_such_module_xyz:run': no module"),
    ("ep_plugin_bad:run", "importing 'ep_plugin_bad' for method 'ep_plugin_bad:run' failed: ZeroDivisionError: "),
    ("jacobi_uzawa:nope", "module 'jacobi_uzawa' has no attribute 'nope'"),
    ("jacobi_uzawa:CHECK_EVERY", "'jacobi_uzawa:CHECK_EVERY' is 50 (int), neither a Method"),
    ("jacobi_uzawa:project", "'jacobi_uzawa:project' cannot be called as run(disc, options)"),
    ("ep_plugin_bad2:METHOD", "'ep_plugin_bad2:METHOD' is a Method whose options <class 'dict'> are not a class"),
    ("not a:spec", "'not a:spec' is not package.module:function"),
    ("no-such-method", "unknown method 'no-such-method' (choose from ["),
])
def test_loading_errors_are_input_errors_in_one_line(example, tmp_path, monkeypatch, capsys, method, message):
    monkeypatch.syspath_prepend(str(tmp_path))
    write_module(tmp_path, "ep_plugin_bad", "x = 1 / 0\n")
    write_module(tmp_path, "ep_plugin_bad2", """
        from elastoplast.solvers.registry import Method
        METHOD = Method("bad", lambda disc, options: None, dict, "options that are no SolverOptions")
    """)
    out = tmp_path / "out"
    assert main(["solve", str(SMALL), "--method", method, "--out", str(out), "--quiet"]) == 2
    line = one_error_line(capsys)
    assert line.startswith(f"error: --method: {message}"), line
    assert not out.exists()
    # the same from Python and from a campaign's method axis, naming where the name came from
    with pytest.raises(ep.InputError, match="^method: "):
        ep.solve(ep.discretize(ep.load_problem(SMALL)), method)
    path = tmp_path / "c.toml"
    path.write_text(f'[campaign]\nproblem = "{SMALL}"\n\n[sweep]\nmethod = ["conic", {json.dumps(method)}]\n')
    assert main(["campaign", str(path), "--out", str(tmp_path / "store"), "--quiet"]) == 2
    assert one_error_line(capsys).startswith("error: sweep.solver.method: ")
    # an option the method lacks is refused like for a built-in
    if method == "no-such-method":
        assert main(["solve", str(SMALL), "--method", "jacobi_uzawa:run", "--rho", "1e-6", "--out", str(out),
                     "--quiet"]) == 2
        assert one_error_line(capsys).startswith("error: --rho: method 'jacobi_uzawa:run' has no option 'rho'")


def test_plugin_that_raises(tmp_path, monkeypatch, capsys, disc):
    """A bug in a plug-in is exit 3 naming it (its traceback kept as the cause); an
    InputError it raises is bad input, exit 2; an answer of no known form is its bug."""
    monkeypatch.syspath_prepend(str(tmp_path))
    write_module(tmp_path, "ep_plugin_raises", """
        import elastoplast as ep

        def run(disc, options):
            raise ValueError("boom\\nsecond line")

        def refuses(disc, options):
            raise ep.InputError("mesh", "this method solves 3D problems only")

        def garbage(disc, options):
            return 42

        def bad_shape(disc, options):
            return [[0.0, 0.0]], 0.0

        def bad_check(disc, options):
            raise KeyError("oops")

        from elastoplast.solvers.registry import Method
        CHECKED = Method("checked", garbage, ep.SolverOptions, "its check fails", bad_check)
    """)
    with pytest.raises(PluginError, match=r"^method 'ep_plugin_raises:run' raised ValueError: boom$") as info:
        ep.solve(disc, "ep_plugin_raises:run")
    assert isinstance(info.value.__cause__, ValueError)
    with pytest.raises(PluginError, match=r"returned 42: expected a Solution, \(u, U\) or \(u, U, sigma, xi\)"):
        ep.solve(disc, "ep_plugin_raises:garbage")
    with pytest.raises(PluginError, match=r"returned a bad answer: u: "):
        ep.solve(disc, "ep_plugin_raises:bad_shape")
    with pytest.raises(PluginError, match=r"^method 'ep_plugin_raises:CHECKED': its check raised KeyError: 'oops'$"):
        ep.solve(disc, "ep_plugin_raises:CHECKED")
    args = ["solve", str(SMALL), "--out", str(tmp_path / "out"), "--quiet", "--method"]
    assert main([*args, "ep_plugin_raises:run"]) == 3
    line = one_error_line(capsys)
    assert "PluginError: method 'ep_plugin_raises:run' raised ValueError: boom" in line
    assert main([*args, "ep_plugin_raises:refuses"]) == 2
    assert one_error_line(capsys) == "error: mesh: this method solves 3D problems only"
    assert not (tmp_path / "out").exists()


def test_entry_points_found_by_name(example, tmp_path, monkeypatch, capsys, disc):
    """The example's pyproject entry point, installed: found by its name; one that
    fails to load names its distribution; one named like a built-in never wins; a
    name two distributions declare is ambiguous."""
    declared = tomllib.loads((EXAMPLE / "pyproject.toml").read_text())["project"]["entry-points"][GROUP]
    assert declared == {"jacobi-uzawa": "jacobi_uzawa:METHOD"}
    declare_entry_points(tmp_path, "ep-test-methods", {**declared, "broken-method": "no_such_module_q:run",
                                                       "uzawa": "jacobi_uzawa:run", "twice": "jacobi_uzawa:run"})
    other = tmp_path / "other"
    other.mkdir()
    declare_entry_points(other, "ep-test-others", {"twice": "jacobi_uzawa:METHOD"})
    monkeypatch.syspath_prepend(str(other))
    monkeypatch.syspath_prepend(str(tmp_path))

    with pytest.warns(UserWarning, match=r"entry point 'uzawa' \(jacobi_uzawa:run\) of distribution ep-test-methods "
                                         r"1.0 has the name of a built-in method: the built-in wins"):
        sol = ep.solve(disc, "jacobi-uzawa")
    assert sol.converged and sol.method == "jacobi-uzawa"
    assert type(method_options("jacobi-uzawa")).__name__ == "JacobiOptions"
    assert get_method("uzawa") is METHODS["uzawa"]

    with pytest.raises(ep.InputError, match=r"^method: method 'twice' is declared by 2 entry points"):
        get_method("twice")
    with pytest.raises(ep.InputError, match=r"the installed \[") as exc:
        get_method("no-such-method")
    listed = exc.value.message.split("the installed ")[1]
    assert all(repr(name) in listed for name in ("broken-method", "jacobi-uzawa", "twice")), listed
    assert main(["solve", str(SMALL), "--method", "broken-method", "--out", str(tmp_path / "out"), "--quiet"]) == 2
    line = one_error_line(capsys)
    assert line.startswith("error: --method: entry point 'broken-method' = 'no_such_module_q:run' of distribution "
                           "ep-test-methods 1.0 failed to load: ModuleNotFoundError: "), line


def test_entry_point_lookup_reads_importlib_metadata(example, monkeypatch, disc):
    """The registry reads ``importlib.metadata.entry_points`` at each lookup: one
    registered at run time is found by name."""
    import importlib.metadata as metadata

    found = metadata.EntryPoints([metadata.EntryPoint("late-method", "jacobi_uzawa:METHOD", GROUP)])
    real = metadata.entry_points
    monkeypatch.setattr(metadata, "entry_points", lambda **kw: found if kw.get("group") == GROUP else real(**kw))
    assert get_method("late-method").options.__name__ == "JacobiOptions"
    assert ep.solve(disc, "late-method", tol=1e-4).converged
