"""Campaigns on Dask: stored, resumable, comparable (issue 6).

Every case is a tiny plane-strain problem (problems/cylinder_2d.toml coarsened).
The solvers are deterministic (Clarabel with QDLDL, single-threaded workers), so
a case run in a Dask worker must reproduce a solve in this process bit for bit:
"identical" below means ``np.array_equal``, not a tolerance.
"""

from __future__ import annotations

import copy
import json
import logging
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import meshio
import numpy as np
import pytest

import elastoplast as ep
from elastoplast.certificate.kkt import energy_norm_sq
from elastoplast.solvers.registry import Method
from elastoplast.studies.compare import compare
from elastoplast.studies.campaign import load_campaign, run_campaign
from elastoplast.cli.main import main
from elastoplast.io.store import ERROR, Store, resolve

ROOT = Path(__file__).resolve().parents[1]
BASE = ROOT / "problems" / "cylinder_2d.toml"
ARRAYS = ("sigma", "xi", "u", "contact_force", "contact_pressure", "active", "plastic")


def write_campaign(path: Path, sweep: str, divisions=(12, 6), solver: str = "") -> Path:
    """A campaign on the cylinder problem with a ``[sweep]`` table given as TOML lines."""
    path.write_text(
        f'[campaign]\nproblem = "{BASE}"\n\n[mesh]\ndivisions = {list(divisions)}\n\n'
        f"[solver]\n{solver}\n\n[sweep]\n{sweep}\n"
    )
    return path


def solve_alone(params: dict, divisions=(12, 6), solver: dict | None = None):
    """The case solved in this process, from the problem file, without the campaign code."""
    data = ep.read_toml(BASE)
    data["mesh"]["divisions"] = list(divisions)
    settings = dict(solver or {})
    for key, value in params.items():
        section, name = key.split(".")
        if section == "solver":
            settings[name] = value
        else:
            data[section][name] = value
    disc = ep.discretize(ep.problem_from_dict(data, BASE.parent))
    method = settings.pop("method", "conic")
    return disc, ep.solve(disc, method, **settings)


def index_rows(out: Path, while_running: bool = False) -> list[dict]:
    """The stored cases' rows. ``while_running``: polled while the campaign starts, when the
    index file may exist before its table does (no rows yet, not an error)."""
    if not (out / "index.sqlite").is_file():
        return []
    con = sqlite3.connect(out / "index.sqlite", timeout=30)
    con.row_factory = sqlite3.Row
    try:
        table = con.execute("SELECT 1 FROM sqlite_master WHERE type = 'table' AND name = 'cases'").fetchone()
        if while_running and table is None:
            return []
        return [dict(r) for r in con.execute("SELECT * FROM cases")]
    finally:
        con.close()


def assert_store_complete(out: Path, expected_ids: set[str]) -> None:
    """Every case exactly once in the index and on disk, and every file readable."""
    rows = index_rows(out)
    assert sorted(r["id"] for r in rows) == sorted(expected_ids)  # no duplicate, none missing
    assert {p.name for p in (out / "cases").iterdir()} == expected_ids  # no temporary or orphan folder
    for row in rows:
        folder = out / "cases" / row["id"]
        summary = json.loads((folder / "summary.json").read_text())
        json.loads((folder / "input.json").read_text())
        with np.load(folder / "mesh.npz") as z:
            [z[k] for k in z.files]
        if row["status"] == ERROR:
            continue
        with np.load(folder / "solution.npz") as z:
            arrays = {k: z[k] for k in z.files}
        assert float(arrays["U"]) == summary["U"] == row["U"]
        vtu = meshio.read(folder / "solution.vtu")
        np.testing.assert_array_equal(vtu.point_data["displacement"][:, :2], arrays["u"])


@pytest.fixture(scope="module")
def client():
    """Two single-threaded worker processes, as on this 2-core machine."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}, silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as c:
        yield c


FORCES = [1000.0, 4315.0]  # elastic, and the plastic case of problems/cylinder_2d.toml
METHODS = ["conic", "conic-displacement"]


@pytest.fixture(scope="module")
def reference_store(tmp_path_factory, client):
    tmp = tmp_path_factory.mktemp("refs")
    path = write_campaign(tmp / "c.toml", f'"load.force" = {FORCES}\nmethod = {json.dumps(METHODS)}',
                          solver="tol = 1e-10")
    campaign = load_campaign(path)
    run = run_campaign(campaign, tmp / "store", client=client, progress=False)
    return path, campaign, run, tmp / "store"


def test_campaign_equals_solving_each_case_alone(reference_store):
    path, campaign, run, out = reference_store
    assert len(campaign.cases) == len(FORCES) * len(METHODS)  # the product of the axes
    assert run.failed == {} and len(run.statuses) == len(campaign.cases) and run.skipped == ()
    assert_store_complete(out, {c.case_id for c in campaign.cases})
    store = Store(out)
    for row in store.rows():
        params = json.loads(row["params"])
        disc, alone = solve_alone(params, solver={"tol": 1e-10})
        stored = store.load_solution(row["id"])
        for name in ARRAYS:
            assert np.array_equal(getattr(stored, name), getattr(alone, name)), name
        assert stored.U == alone.U == row["U"]
        assert stored.kkt == alone.kkt and stored.status is alone.status is ep.Status.CONVERGED
        assert row["kkt_worst"] == alone.kkt.worst and row["method"] == params["solver.method"]
        # the stored arrays are complete: certifying them again gives the same certificate
        again = store.load_solution(row["id"], disc, recertify=True)
        assert again.kkt == stored.kkt and again.value_S == stored.value_S and again.duality_gap == stored.duality_gap
        # the stored input rebuilds the same problem (its hash is the case id)
        assert store.load_input(row["id"]).case_id == row["id"]


def test_rerun_skips_stored_cases_and_new_axis_values_add_only_new_cases(reference_store, client, tmp_path):
    import shutil

    path, campaign, _, shared = reference_store
    out = tmp_path / "store"
    shutil.copytree(shared, out)  # the other tests keep the shared store as it was
    again = run_campaign(load_campaign(path), out, client=client, progress=False)
    assert again.statuses == {} and set(again.skipped) == {c.case_id for c in campaign.cases}
    before = {r["id"]: r["finished_at"] for r in index_rows(out)}

    grown = write_campaign(tmp_path / "grown.toml", f'"load.force" = {FORCES + [2000.0]}\n'
                           f"method = {json.dumps(METHODS)}", solver="tol = 1e-10")
    bigger = load_campaign(grown)
    run = run_campaign(bigger, out, client=client, progress=False)
    assert len(run.statuses) == len(METHODS)  # one new force value times the methods
    assert {json.loads(Store(out).row(i)["params"])["load.force"] for i in run.statuses} == {2000.0}
    after = {r["id"]: r["finished_at"] for r in index_rows(out)}
    assert {k: after[k] for k in before} == before  # the old cases were not rewritten
    assert_store_complete(out, {c.case_id for c in bigger.cases})


def test_compare_reports_errors_against_each_reference(reference_store, client, tmp_path):
    _, campaign, _, out = reference_store
    report = compare(out, "conic-displacement", options={"tol": 1e-10}, client=client, progress=False,
                        out=tmp_path / "report")
    store = Store(out)
    assert len(report.rows) == len(campaign.cases) and report.summary["n_problems"] == len(FORCES)
    for row in report.rows:
        ref = store.load_solution(row["case"])
        disc, alone = solve_alone(json.loads(store.row(row["case"])["params"]) | {"solver.method": "conic-displacement"},
                                  solver={"tol": 1e-10})
        # the definitions of the report, computed here by hand
        assert row["U_rel"] == pytest.approx(abs(alone.U - ref.U) / abs(ref.U), rel=1e-12, abs=1e-300)
        num = energy_norm_sq(disc, alone.sigma - ref.sigma, alone.xi - ref.xi)
        den = energy_norm_sq(disc, ref.sigma, ref.xi)
        assert row["sigma_rel"] == pytest.approx(np.sqrt(num / den), rel=1e-12, abs=1e-300)
        assert row["time_ratio"] == pytest.approx(row["time_s"] / ref.time_s, rel=1e-12)
        if row["reference_method"] == "conic-displacement":  # the same deterministic solve
            assert row["U_rel"] == 0.0 and row["sigma_rel"] == 0.0
    md = (tmp_path / "report" / "report.md").read_text()
    assert md.count("\n| ") == 1 + len(campaign.cases)  # header and one row per reference case
    assert (tmp_path / "report" / "compare.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(json.loads((tmp_path / "report" / "compare.json").read_text())["rows"]) == len(campaign.cases)


@pytest.mark.parametrize(
    "sweep, axis",
    [
        ('"load.force" = [1000.0, -5.0]', "sweep.load.force"),  # problem/definition.py: force must be > 0
        ('"material.hardness" = [1.0]', "sweep.material.hardness"),  # not a key of [material]
        ('"material.hardening" = []', "sweep.material.hardening"),  # no case at all
        # the contact nodes reach x = 20 (2/6)^2 = 2.2 (12 divisions of 40 graded by 2): wider than R = 1
        ('"obstacle.radius" = [40.0, 1.0]', "sweep.obstacle.radius"),
        ('method = ["conic", "no-such-method"]', "sweep.solver.method"),
        ('"solver.tol" = [0.0]', "sweep.solver.tol"),
    ],
)
def test_invalid_sweep_is_reported_before_running_naming_the_axis(tmp_path, capsys, sweep, axis):
    path = write_campaign(tmp_path / "bad.toml", sweep)
    assert main(["campaign", str(path), "--out", str(tmp_path / "store"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {axis}: "), err
    assert not (tmp_path / "store").exists()  # nothing ran, nothing was written


def test_case_failing_at_run_time_is_recorded_while_others_complete(tmp_path, monkeypatch):
    """A method that raises, and Clarabel stopped after one iteration: both recorded
    as failed; the other cases complete. Threads, so the test's method is seen."""
    from distributed import Client, LocalCluster

    def broken(disc, options):
        raise RuntimeError("forced failure for the test")

    monkeypatch.setitem(ep.METHODS, "broken", Method("broken", broken, ep.ConicOptions, "raises"))
    path = write_campaign(tmp_path / "c.toml", 'method = ["conic", "broken"]\n"solver.max_iter" = [1, 200]')
    campaign = load_campaign(path)
    out = tmp_path / "store"
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None,
                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}, silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client:
        run = run_campaign(campaign, out, client=client, progress=False)
        by_point = {(r["method"], json.loads(r["options"])["max_iter"]): r for r in index_rows(out)}
        assert {k: r["status"] for k, r in by_point.items()} == {
            ("conic", 1): "max_iterations", ("conic", 200): "converged", ("broken", 1): ERROR, ("broken", 200): ERROR}
        assert by_point[("broken", 1)]["error"] == "RuntimeError: forced failure for the test"
        assert "forced failure" in json.loads((out / "cases" / by_point[("broken", 1)]["id"] / "summary.json")
                                              .read_text())["traceback"]
        assert set(run.failed) == {by_point[k]["id"] for k in [("conic", 1), ("broken", 1), ("broken", 200)]}
        assert_store_complete(out, {c.case_id for c in campaign.cases})

        # resume retries what raised, keeps solver outcomes; --retry-failed re-runs those too
        again = run_campaign(campaign, out, client=client, progress=False)
        assert set(again.statuses) == {by_point[("broken", m)]["id"] for m in (1, 200)}
        again = run_campaign(campaign, out, client=client, progress=False, retry_failed=True)
        assert set(again.statuses) == set(run.failed)
        assert_store_complete(out, {c.case_id for c in campaign.cases})


def _kill_group(proc: subprocess.Popen) -> None:
    """Kill what is left of a process group this test started (its leader's id)."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(timeout=30)


def test_sigkill_mid_campaign_then_rerun_completes_each_case_once(tmp_path, capsys):
    # 12 cases of ~1 s each (64 x 32 elements): the kill lands while most still run, even
    # when a loaded machine starves this test's polling loop for a few seconds
    forces = [1000.0 + 300.0 * i for i in range(12)]
    path = write_campaign(tmp_path / "c.toml", f'"load.force" = {forces}', divisions=(64, 32))
    out = tmp_path / "store"
    log = open(tmp_path / "first.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "elastoplast", "campaign", str(path), "--out", str(out),
                             "--quiet", "--workers", "2"], cwd=tmp_path, stdout=log, stderr=log, start_new_session=True,
                            env={**os.environ, "DASK_TEMPORARY_DIRECTORY": str(tmp_path / "dask")})
    try:
        deadline = time.monotonic() + 90
        while len(index_rows(out, while_running=True)) < 2:
            assert proc.poll() is None, (tmp_path / "first.log").read_text()
            assert time.monotonic() < deadline, "no case finished in time"
            time.sleep(0.02)
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL
    finally:
        _kill_group(proc)  # the local cluster's workers, if they outlive their parent
        log.close()
    done = index_rows(out)
    assert 2 <= len(done) < len(forces), "the kill did not land mid-campaign"
    stamps = {r["id"]: r["finished_at"] for r in done}

    assert main(["campaign", str(path), "--out", str(out), "--quiet", "--workers", "2"]) == 0
    line = capsys.readouterr().out
    assert f"{len(forces) - len(done)} run, {len(done)} already stored" in line, line
    campaign = load_campaign(path)
    assert_store_complete(out, {c.case_id for c in campaign.cases})
    assert {r["id"]: r["finished_at"] for r in index_rows(out) if r["id"] in stamps} == stamps


def test_campaign_through_a_scheduler_and_two_worker_processes(tmp_path, capsys):
    from distributed import Client

    dask = str(Path(sys.executable).with_name("dask"))
    sched_file = tmp_path / "scheduler.json"
    procs: list[subprocess.Popen] = []
    logs = open(tmp_path / "dask.log", "w")

    def start(*args: str) -> None:
        procs.append(subprocess.Popen([dask, *args], cwd=tmp_path, stdout=logs, stderr=logs, start_new_session=True))

    try:
        start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--dashboard-address", "127.0.0.1:0",
              "--scheduler-file", str(sched_file))
        deadline = time.monotonic() + 60
        while not sched_file.is_file() or not sched_file.read_text().strip():
            assert procs[0].poll() is None and time.monotonic() < deadline, (tmp_path / "dask.log").read_text()
            time.sleep(0.1)
        time.sleep(0.1)  # the file is written in one go, but be sure it is complete
        address = json.loads(sched_file.read_text())["address"]
        for i in range(2):
            start("worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-nanny", "--no-dashboard",
                  "--name", f"w{i}", "--local-directory", str(tmp_path / f"w{i}"))
        with Client(address, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
            workers = set(c.scheduler_info()["workers"])
        path = write_campaign(tmp_path / "c.toml", '"load.force" = [1000.0, 2000.0, 3000.0, 4315.0]\n'
                              '"material.hardening" = [10000.0, 100000.0]', solver="tol = 1e-10")
        out = tmp_path / "store"
        assert main(["campaign", str(path), "--out", str(out), "--scheduler", address, "--quiet"]) == 0
        rows = index_rows(out)
        assert {r["worker"] for r in rows} == workers  # both worker processes took cases
        campaign = load_campaign(path)
        assert_store_complete(out, {c.case_id for c in campaign.cases})
        for row in rows[:2]:  # the same results as solving alone
            _, alone = solve_alone(json.loads(row["params"]), solver={"tol": 1e-10})
            assert row["U"] == alone.U and row["kkt_worst"] == alone.kkt.worst
    finally:
        for proc in reversed(procs):
            try:
                os.killpg(proc.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for proc in reversed(procs):
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                _kill_group(proc)
        logs.close()
    capsys.readouterr()


def test_case_id_hashes_the_resolved_input(tmp_path, monkeypatch):
    """Equal inputs resolve alike; any change of mesh, parameter, tolerance or version is a new case."""
    data = ep.read_toml(BASE)
    data["mesh"]["divisions"] = [12, 6]

    def case_id(d, method="conic", options=None):
        return resolve(ep.problem_from_dict(d, BASE.parent), method, options or {}).case_id

    ref = case_id(data)
    sphere = copy.deepcopy(data)
    sphere["obstacle"]["shape"] = "sphere"  # problem/definition.py: a 2D sphere is the cylinder
    assert case_id(sphere) == ref
    finer = copy.deepcopy(data)
    finer["mesh"]["divisions"] = [12, 8]
    graded = copy.deepcopy(data)
    graded["mesh"]["grading"] = 1.5  # same sizes, other node positions
    assert len({ref, case_id(finer), case_id(graded), case_id(data, options={"tol": 1e-9}),
                case_id(data, method="conic-displacement")}) == 5
    monkeypatch.setattr("elastoplast.io.store.__version__", "0.0.0-test")
    assert case_id(data) != ref


def test_store_write_is_atomic_over_a_crash_between_folder_and_index(tmp_path):
    """A folder moved into place without its row (a crash before indexing) and a
    left-over temporary folder are both invisible and repaired on the next write."""
    from elastoplast.io.store import case_record

    disc, sol = solve_alone({"load.force": 1000.0})
    inp = resolve(disc.problem, "conic", {})
    store = Store(tmp_path / "store")
    record = case_record(inp, {"load.force": 1000.0}, "test", solution=sol, summary=ep.summary(disc, sol))
    with store.writer():
        pass
    folder = store.case_dir(inp.case_id)
    folder.mkdir()
    (folder / "summary.json").write_text("{ half")  # what a crash could leave
    (store.path / "cases" / ".tmp-crashed").mkdir()
    assert store.rows() == []  # not visible: no index row
    with store.writer():  # sweeps the temporary folder
        assert not (store.path / "cases" / ".tmp-crashed").exists()
        store.add(record)
    assert [r["id"] for r in store.rows()] == [inp.case_id]
    assert json.loads((folder / "summary.json").read_text())["U"] == sol.U
    assert np.array_equal(store.load_solution(inp.case_id).sigma, sol.sigma)


def test_compare_command_line(reference_store, client, tmp_path, capsys):
    _, campaign, _, out = reference_store
    args = ["compare", str(out), "--tol", "1e-10", "--scheduler", client.scheduler.address, "--quiet",
            "--out", str(tmp_path / "report")]
    assert main([*args, "--method", "conic", "--reference-method", "conic"]) == 0
    table = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")][1:]
    assert len(table) == len(FORCES)  # the conic references only
    for line in table:  # the same deterministic solver on the same input: no error at all
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[3] == "converged" and cells[6] == cells[7] == "0.00e+00", line
    assert main([*args, "--method", "no-such-method"]) == 2
    assert capsys.readouterr().err.startswith("error: --method: unknown method 'no-such-method'")


def test_adaptive_target_per_case(client, tmp_path):
    """A campaign case with an [adapt] table runs the adaptive loop to its rtol and
    stores the final mesh, its solution and its certified bounds; the stored
    solution re-certifies on the stored final mesh (load_problem gives that mesh)."""
    path = tmp_path / "c.toml"
    path.write_text(f'[campaign]\nproblem = "{BASE}"\n\n[mesh]\ndivisions = [10, 5]\n\n[solver]\nmethod = "newton"\n\n'
                    '[adapt]\nbracket = "final"\ncompare_uniform = false\n\n[sweep]\n"adapt.rtol" = [0.2, 0.05]\n')
    campaign = load_campaign(path)
    assert len(campaign.cases) == 2 and all("adapt" in c.input.spec for c in campaign.cases)
    out = tmp_path / "store"
    run_campaign(campaign, out, client=client, progress=False)
    store = Store(out)
    rows = {json.loads(r["params"])["adapt.rtol"]: r for r in store.rows()}
    for rtol, row in rows.items():
        assert row["status"] == "converged" and row["bounds_certified"] == 1
        assert row["energy_gap_rel"] <= rtol
        assert row["energy_lower"] <= row["energy_upper"] and row["U_lower"] <= row["U"] <= row["U_upper"]
        problem = store.load_problem(row["id"])  # the adapted mesh
        assert problem.mesh.n_elements == row["final_elements"] > row["n_elements"]
        sol = store.load_solution(row["id"], recertify=True)
        assert sol.kkt.worst <= 1e-8  # the case's tol (AdaptOptions.tol) on the adapted mesh
    assert rows[0.05]["final_elements"] > rows[0.2]["final_elements"]  # a tighter target takes more elements
    # an [adapt] option out of range is refused at load, naming the axis
    bad = tmp_path / "bad.toml"
    bad.write_text(path.read_text().replace('[0.2, 0.05]', '[0.2, 0.0]'))
    with pytest.raises(ep.InputError) as exc:
        load_campaign(bad)
    assert exc.value.field == "sweep.adapt.rtol"
