"""Loading paths around the solver: the problem file's ``[load] path``, ``elastoplast
solve`` on a path and its files, the commands that refuse a path, campaigns, ``compare``
and suites with a path.

Origins of the numbers asserted:

* a path's summary holds one entry per force of the file, in the file's order, and
  the output folder one ``solution_NNN.vtu`` per step run, each listed by ``path.pvd``
  (the output format, docs/evolution.md, section 7);
* the residual imprint and the unloading slope are read off the steps by their
  definitions (the smallest force of the first unloading; the secant of its first step);
* the displacement written per step is the *total* one: the contact conditions hold on
  the total gap ``u_d + psi - U`` (>= 0 to the certificate's tolerance, 0 at the active
  nodes), which the increment would not satisfy after the first step;
* kappa, the accumulated equivalent plastic strain, never decreases along a path;
* two certified methods agree on U at every step to the 1e-5 the issue asks of them.
"""

from __future__ import annotations

import copy
import json
import logging
import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest

import elastoplast as ep
from elastoplast.cli.main import main
from elastoplast.errors import InputError
from elastoplast.io.store import Store, rebuild_problem, resolve
from elastoplast.problem.load import check_forces
from elastoplast.solvers.path import check_path

from conftest import PROBLEMS
from test_cli import write_toml

F = 4000.0
#: load, unload in two steps to a small force, reload past the first maximum
PATH = [0.5 * F, F, F / 3, 0.05 * F, 1.2 * F]


def path_dict(path=PATH, divisions=(20, 10)) -> dict:
    data = ep.read_toml(PROBLEMS / "indentation_path_2d.toml")
    data["mesh"]["divisions"] = list(divisions)
    data["load"] = {"path": list(path)}
    return data


def problem_of(data: dict) -> ep.Problem:
    return ep.problem_from_dict(copy.deepcopy(data), base_dir=PROBLEMS)


# ----------------------------------------------------------------------------
# the problem file
# ----------------------------------------------------------------------------


def test_a_path_is_read_in_order_and_its_force_is_the_largest():
    problem = problem_of(path_dict())
    assert problem.path == tuple(PATH)
    assert problem.force == max(PATH)
    hencky = problem_of({**path_dict(), "load": {"force": F}})
    assert hencky.path is None and hencky.force == F


def test_the_shipped_example_is_a_load_unload_reload_path():
    problem = ep.load_problem(PROBLEMS / "indentation_path_2d.toml")
    forces = np.array(problem.path)
    peak = int(np.argmax(forces[: np.flatnonzero(np.diff(forces) < 0)[0] + 1]))
    assert np.any(np.diff(forces) < 0)  # unloads
    assert forces.max() > forces[peak]  # reloads beyond the first maximum
    assert problem.force == forces.max()


@pytest.mark.parametrize("load,field", [
    ({"force": F, "path": [F]}, "load"),
    ({}, "load.force"),
    ({"path": [F], "pressure": 1.0}, "load.pressure"),
])
def test_exactly_one_of_force_and_path(load, field):
    with pytest.raises(InputError) as err:
        problem_of({**path_dict(), "load": load})
    assert err.value.field == field


@pytest.mark.parametrize("bad,words", [
    ([], "empty"), ([1.0, 0.0], "entry 2"), ([1.0, -2.0], "entry 2"), ([float("nan")], "entry 1"),
    ([float("inf")], "entry 1"),
    ([10**400], "entry 1"),
    (["1"], "entry 1"), ([True], "entry 1"),
    ([[1.0]], "entry 1"), ("1, 2", "list"), (3.0, "list"), ({"a": 1.0}, "list"),
])
def test_a_bad_path_is_refused_naming_load_path_and_the_entry(bad, words):
    with pytest.raises(InputError) as err:
        problem_of({**path_dict(), "load": {"path": bad}})
    assert err.value.field == "load.path" and words in err.value.message
    # the solver's own check refuses the same inputs
    with pytest.raises(InputError, match=words if words != "list" else None):
        check_path(bad)


@pytest.mark.parametrize("good", [[1.0], [3, 1, 2], (2.5, 0.1, 7.0), np.array([1.0, 2.0])])
def test_good_paths_pass_both_checks_alike(good):
    assert check_forces(good) == check_path(good) == tuple(float(f) for f in good)


def test_with_force_and_with_path():
    problem = problem_of(path_dict())
    assert problem.with_force(F).path is None and problem.with_force(F).force == F
    again = problem.with_force(F).with_path([1.0, 3.0, 2.0])
    assert again.path == (1.0, 3.0, 2.0) and again.force == 3.0
    with pytest.raises(InputError, match="entry 2"):
        problem.with_path([1.0, 0.0])


def test_the_store_keeps_the_path_and_hencky_ids_do_not_change():
    problem = problem_of(path_dict())
    inp = resolve(problem, "newton", {})
    assert inp.spec["path"] == PATH
    assert rebuild_problem(inp.spec, inp.arrays).path == tuple(PATH)
    hencky = resolve(problem.with_force(F), "newton", {})
    assert "path" not in hencky.spec  # the ids of Hencky cases stay what they were
    assert rebuild_problem(hencky.spec, hencky.arrays).path is None
    assert hencky.problem_id != inp.problem_id


# ----------------------------------------------------------------------------
# elastoplast solve on a path
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """One run of ``elastoplast solve`` on PATH (newton), and what it printed."""
    tmp = tmp_path_factory.mktemp("path")
    problem = write_toml(tmp / "p.toml", path_dict())
    out = tmp / "out"
    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["solve", str(problem), "--method", "newton", "--out", str(out)])
    return code, out, err.getvalue(), problem


def test_solve_on_a_path_writes_every_step(solved):
    code, out, err, _ = solved
    assert code == 0
    names = {p.name for p in out.iterdir()}
    steps = [f"solution_{i:03d}.vtu" for i in range(1, len(PATH) + 1)]
    assert set(steps) | {"summary.json", "path.pvd", "path.png"} <= names
    assert (out / "path.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    summary = json.loads((out / "summary.json").read_text())
    assert [e["step"] for e in summary["path"]] == list(range(1, len(PATH) + 1))
    assert [e["force"] for e in summary["path"]] == PATH
    assert all(e["status"] == "converged" for e in summary["path"])
    assert summary["status"] == "converged" and summary["force"] == max(PATH)
    assert summary["U"] == summary["path"][-1]["U"]
    assert summary["kkt_worst"] == max(e["kkt_worst"] for e in summary["path"])
    assert "provenance" in summary and summary["files"] == steps
    # one progress line per step on stderr
    assert [line.split("]")[0] for line in err.splitlines() if line.startswith("[")] == \
        [f"[{i}/{len(PATH)}" for i in range(1, len(PATH) + 1)]


def test_the_collection_lists_the_step_files_in_order(solved):
    _, out, _, _ = solved
    root = ET.parse(out / "path.pvd").getroot()
    assert root.get("type") == "Collection"
    sets = root.find("Collection").findall("DataSet")
    assert [d.get("file") for d in sets] == [f"solution_{i:03d}.vtu" for i in range(1, len(PATH) + 1)]
    assert [float(d.get("timestep")) for d in sets] == [float(i) for i in range(1, len(PATH) + 1)]
    assert all((out / d.get("file")).is_file() for d in sets)


def test_imprint_and_unloading_slope_follow_their_definitions(solved):
    _, out, _, _ = solved
    summary = json.loads((out / "summary.json").read_text())
    steps = summary["path"]
    # the first unloading is steps 3 and 4 (F/3, then 0.05 F), from the peak at step 2
    assert [e["unloading"] for e in steps] == [False, False, True, True, False]
    imprint, slope = summary["residual_imprint"], summary["unloading_slope"]
    assert imprint["step"] == 4 and imprint["U"] == steps[3]["U"] and imprint["force"] == PATH[3]
    assert slope["step"] == 3
    assert slope["S"] == pytest.approx((PATH[1] - PATH[2]) / (steps[1]["U"] - steps[2]["U"]), rel=1e-14)
    # U grows with F on the elastic unloading branch: the imprint lies between 0 and the peak
    assert 0.0 < imprint["U"] < steps[1]["U"] and slope["S"] > 0.0


def test_the_summary_reads_the_imprint_as_the_path_result_does():
    """Two cycles: the imprint is U at the end of the last unloading, as
    PathResult.residual_imprint() gives it; the slope is the first unloading step's secant."""
    from elastoplast.io.loading_path import residual_imprint, unloading_slope

    problem = problem_of(path_dict(path=[F, 0.3 * F, 0.1 * F, F, 1.1 * F, 0.2 * F], divisions=(12, 6)))
    result = ep.solve_path(ep.discretize(problem), problem.path, "newton")
    imprint, slope = residual_imprint(result), unloading_slope(result)
    assert imprint["U"] == result.residual_imprint() == result.steps[5].U
    assert imprint["step"] == 6 and imprint["F_peak"] == 1.1 * F
    U = result.U
    assert slope["step"] == 2 and slope["S"] == (F - 0.3 * F) / (U[0] - U[1])


def test_each_step_file_holds_the_total_displacement(solved):
    _, out, _, problem = solved
    disc = ep.discretize(ep.load_problem(problem))
    summary = json.loads((out / "summary.json").read_text())
    kappa_before = np.zeros(disc.n_elements)
    for entry in summary["path"]:
        vtu = meshio.read(out / f"solution_{entry['step']:03d}.vtu")
        u = vtu.point_data["displacement"][:, :2]
        gap = u[disc.contact_nodes, 1] + disc.psi - entry["U"]
        scale = max(abs(entry["U"]), np.abs(u).max())
        assert gap.min() >= -1e-8 * scale, entry["step"]  # no penetration of the total gap
        assert np.min(np.abs(gap)) <= 1e-8 * scale, entry["step"]  # and contact where the body touches
        kappa = vtu.cell_data["kappa"][0]
        assert np.all(kappa >= kappa_before) and {"dkappa", "yielded", "plastic_ever", "stress", "xi"} <= set(
            vtu.cell_data)
        np.testing.assert_array_equal(vtu.cell_data["plastic_ever"][0], (kappa > 0).astype(np.int32))
        kappa_before = kappa


def test_quiet_prints_no_step_lines(tmp_path, capsys):
    problem = write_toml(tmp_path / "p.toml", path_dict(path=[F, 0.5 * F], divisions=(12, 6)))
    assert main(["solve", str(problem), "--method", "newton", "--quiet", "--out", str(tmp_path / "o")]) == 0
    out, err = capsys.readouterr()
    assert "[1/2]" not in err and "converged: 2 of 2 steps converged" in out


def test_a_step_that_fails_makes_the_exit_code_nonzero(tmp_path, capsys):
    problem = write_toml(tmp_path / "p.toml", path_dict(divisions=(12, 6)))
    out = tmp_path / "o"
    assert main(["solve", str(problem), "--method", "newton", "--max-iter", "1", "--out", str(out)]) == 1
    capsys.readouterr()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] != "converged" and summary["path"][-1]["status"] != "converged"
    assert len(summary["path"]) <= len(PATH) and summary["forces"] == PATH
    sets = ET.parse(out / "path.pvd").getroot().find("Collection").findall("DataSet")
    assert len(sets) == len(summary["path"])  # only the steps run
    assert (out / "path.png").is_file()


def test_a_bad_path_in_a_file_is_exit_code_2(tmp_path, capsys):
    problem = write_toml(tmp_path / "p.toml", path_dict(path=[F, 0.0]))
    assert main(["solve", str(problem), "--out", str(tmp_path / "o")]) == 2
    assert "load.path: entry 2" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv", [["bounds", "{p}"], ["adapt", "{p}"], ["check", "{p}", "answer.npz"],
                                  ["export", "{p}", "--out", "{tmp}/x.cbf"]])
def test_commands_for_hencky_refuse_a_path(tmp_path, capsys, argv):
    problem = write_toml(tmp_path / "p.toml", path_dict(divisions=(12, 6)))
    args = [a.format(p=problem, tmp=tmp_path) for a in argv]
    if args[0] in ("bounds", "adapt"):
        args += ["--out", str(tmp_path / "o")]
    assert main(args) == 2
    assert "load.path" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------
# campaigns, compare and suites with a path
# ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def path_store(tmp_path_factory):
    from distributed import Client, LocalCluster

    from elastoplast.studies.campaign import load_campaign, run_campaign

    tmp = tmp_path_factory.mktemp("store")
    paths = [[F, F / 3, 1.2 * F], [0.5 * F, F]]
    (tmp / "c.toml").write_text(
        f'[campaign]\nproblem = "{PROBLEMS / "indentation_path_2d.toml"}"\n\n[mesh]\ndivisions = [12, 6]\n\n'
        f'[solver]\nmethod = "newton"\n\n[sweep]\n"load.path" = {json.dumps(paths)}\n')
    campaign = load_campaign(tmp / "c.toml")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None,
                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}, silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        run_campaign(campaign, tmp / "store", client=client, progress=False)
        yield tmp / "store", paths, client


def test_a_campaign_stores_one_record_per_path(path_store):
    out, paths, _ = path_store
    store = Store(out)
    rows = store.rows()
    assert len(rows) == len(paths) and all(r["status"] == "converged" for r in rows)
    for row in rows:
        steps = store.load_path(row["id"])
        forces = [e["force"] for e in steps]
        assert forces in paths and row["force"] == max(forces)
        assert row["U"] == steps[-1]["U"]
        sol = store.load_solution(row["id"])
        disc = ep.discretize(store.load_problem(row["id"]))
        # the stored u is the total displacement: the contact conditions hold on the total gap
        gap = disc.N @ disc.free_displacement(sol.u) + disc.psi - sol.U
        assert gap.min() >= -1e-8 * sol.U and np.min(np.abs(gap)) <= 1e-8 * sol.U
        with pytest.raises(InputError, match="loading path"):
            store.load_solution(row["id"], recertify=True)


def test_compare_reports_a_path_step_by_step(path_store, tmp_path):
    from elastoplast.studies.compare import compare

    out, paths, client = path_store
    report = compare(out, "conic", client=client, progress=False, out=tmp_path / "cmp")
    assert report.summary["n_converged"] == len(paths)
    for row in report.rows:
        assert [s["force"] for s in row["steps"]] == row["params"]["load.path"]
        assert [s["step"] for s in row["steps"]] == list(range(1, len(row["steps"]) + 1))
        assert all(s["U_rel"] <= 1e-5 for s in row["steps"])  # the agreement of two certified methods
        # the case's U error is the largest of its steps' (the last step's U is the case's U)
        assert row["U_rel"] == max(s["U_rel"] for s in row["steps"])
    text = report.markdown()
    assert "step by step" in text and text.count("| converged |") >= sum(len(p) for p in paths)


def test_a_suite_times_a_path_as_one_instance(tmp_path):
    from elastoplast.studies.suite import run_instance

    problem = write_toml(tmp_path / "p.toml", path_dict(path=[F, 0.5 * F, F], divisions=(12, 6)))
    rec = run_instance({"method": "newton", "options": {"tol": 1e-8, "progress": False}, "problem": str(problem),
                        "name": "p"})
    assert rec["status"] == "converged" and rec["n_steps"] == 3 and rec["kkt_worst"] <= 1e-8
