"""Reference-solution campaigns: sweeps run on Dask, stored, resumable, comparable.

A campaign file is a problem file (same sections, or ``problem = "file.toml"``
in ``[campaign]``) with a ``[sweep]`` table of axes; the cases are the product of
the axes::

    [campaign]
    name = "cylinder-2d"
    problem = "cylinder_2d.toml"    # relative to this file; inline sections override it

    [solver]                        # optional: method (default conic), tol, max_iter, rho
    tol = 1e-10

    [sweep]
    "load.force" = [2000.0, 4315.0]
    material.hardening = [1e4, 1e5] # a dotted key is the same axis
    method = ["conic", "conic-displacement"]

:func:`load_campaign` resolves and validates every case before anything runs
(an :class:`~elastoplast.errors.InputError` naming the axis);
:func:`run_campaign` runs the cases not yet in the store on a Dask cluster and
writes each one as it finishes (:mod:`elastoplast.io.store`);
:func:`~elastoplast.studies.compare.compare` runs another method on every stored
reference and reports its errors (in a script, under ``if __name__ == "__main__":``: the
local cluster starts its workers as processes, which import the script again)::

    from elastoplast.io.store import Store
    from elastoplast.studies.campaign import load_campaign, run_campaign
    from elastoplast.studies.compare import compare

    run_campaign(load_campaign("problems/campaign_2d.toml"), "refs")  # local cluster
    store = Store("refs")
    row = store.rows("status = 'converged' AND json_extract(params, ?) = 4315.0", ('$."load.force"',))[0]
    sol = store.load_solution(row["id"])          # an elastoplast Solution
    problem = store.load_problem(row["id"])       # and its Problem
    report = compare("refs", "conic-displacement")  # refs/compare-conic-displacement/
"""

from __future__ import annotations

import copy
import itertools
import json
import logging
import os
import re
import shutil
import sys
import tempfile
import traceback
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

import numpy as np

from elastoplast.errors import FIELD_WIDTH, InputError, elide
from elastoplast.io.output import path_errors
from elastoplast.io.store import (
    ERROR,
    ResolvedInput,
    Store,
    case_record,
    content_hash,
    rebuild_problem,
    resolve,
)
from elastoplast.limits import as_path
from elastoplast.problem.definition import SECTIONS, problem_from_dict, read_toml
from elastoplast.solvers.registry import check_solvable, method_options, solver_settings
from elastoplast.io.store import STORE_FILES

# ----------------------------------------------------------------------------
# the campaign file
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One sweep point: its axis values and its resolved input (``case_id`` is the hash)."""

    params: Mapping[str, Any]
    input: ResolvedInput
    case_id: str
    problem_id: str


@dataclass(frozen=True)
class Campaign:
    """A validated campaign: its ``axes`` in file order and its distinct ``cases``."""

    name: str
    axes: Mapping[str, tuple]
    cases: tuple[Case, ...]
    #: sweep points that resolved to an earlier case (e.g. "sphere" and "cylinder" in 2D)
    n_duplicates: int = 0


def _axes(sweep: Any) -> dict[str, list]:
    """Flatten ``[sweep]`` into ``{dotted key: values}``; ``method`` means ``solver.method``.
    One axis spelled twice (a quoted key and a dotted one, ``"material.E"`` and
    ``material.E``; ``method`` and ``solver.method``) is refused: TOML keeps both, and
    one of them would vanish."""
    if not isinstance(sweep, Mapping):
        raise InputError("sweep", f"must be a table of axes, got {sweep!r}")
    axes: dict[str, list] = {}
    written: dict[str, str] = {}  # axis -> how the file spells it

    def walk(table: Mapping, prefix: str, spelled: str) -> None:
        for key, val in table.items():
            path = f"{prefix}{key}"
            spelling = spelled + (key if _BARE_KEY.fullmatch(key) else json.dumps(key))
            if isinstance(val, Mapping):
                walk(val, f"{path}.", f"{spelling}.")
                continue
            axis = "solver.method" if path == "method" else path
            if axis in axes:
                raise InputError(f"sweep.{axis}", f"given twice (as {written[axis]} and {spelling}); name each "
                                                  "axis once")
            axes[axis], written[axis] = val, spelling

    walk(sweep, "", "")
    for axis, values in axes.items():
        name = f"sweep.{axis}"
        head = axis.split(".")
        if head[0] not in CASE_SECTIONS or len(head) < 2:
            raise InputError(name, f"unknown key: an axis is 'method' or a dotted key in {sorted(CASE_SECTIONS)}")
        if head[0] == "solver" and len(head) != 2:
            raise InputError(name, "unknown key (a solver axis is 'method' or 'solver.<option>')")
        if not isinstance(values, list):
            raise InputError(name, f"must be a list of values, got {values!r}")
        if not values:
            raise InputError(name, "is an empty list (the campaign would have no case)")
    return axes


#: a TOML key written without quotes
_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")

#: the sections of a case: a problem's, and ``[adapt]`` (an adaptive target, see :func:`adapt_settings`)
CASE_SECTIONS = SECTIONS | {"adapt"}


def adapt_settings(section: Mapping[str, Any] | None, method: str) -> dict[str, Any] | None:
    """The adaptive target of a case from its ``[adapt]`` table (``rtol``, ``theta``,
    ``max_elements``, ``time_limit``, ``bracket``, ...: the options of
    :class:`~elastoplast.adapt.loop.AdaptOptions`), checked; ``None`` without one. The case
    then runs :func:`~elastoplast.adapt.loop.adapt` with the case's method as the P1
    solver, and stores the final mesh, its solution and its bounds."""
    from elastoplast.adapt.records import AdaptOptions

    if section is None:
        return None
    if not isinstance(section, Mapping):
        raise InputError("adapt", f"must be a table, got {section!r}")
    if "method" in section:
        raise InputError("adapt.method", "the P1 solver of an adaptive case is the case's method ([solver] or a "
                                         "method axis)")
    AdaptOptions.build({**section, "method": method}, prefix="adapt.")
    return {k: section[k] for k in sorted(section)}


def _set(data: dict, axis: str, value: Any) -> None:
    keys = axis.split(".")
    node = data
    for i, key in enumerate(keys[:-1]):
        node = node.setdefault(key, {})
        if not isinstance(node, dict):
            raise InputError(f"sweep.{axis}", f"{'.'.join(keys[: i + 1])} is not a table")
    node[keys[-1]] = copy.deepcopy(value)


def _blame(exc: InputError, point: Mapping[str, Any]) -> InputError:
    """Re-raise a problem's complaint about a sweep point under the axis it concerns."""
    for axis, value in point.items():
        named = exc.field in (axis, elide(axis, FIELD_WIDTH))  # a very long axis name comes back cut
        if named or exc.field.startswith(axis + ".") or axis.startswith(exc.field + "."):
            return InputError(f"sweep.{axis}", f"value {value!r}: {exc.field}: {exc.message}")
    where = ", ".join(f"{a} = {v!r}" for a, v in point.items())  # not an axis: the base problem's own field
    return InputError(exc.field, f"{exc.message} (at the sweep point {where})" if where else exc.message)


#: the longest campaign name (it heads every line the command prints)
MAX_NAME = 200


def campaign_from_dict(data: Mapping[str, Any], base_dir: str | Path = ".", name: str = "campaign") -> Campaign:
    """Resolve and validate every case of a campaign given as nested dicts.

    Each sweep point is built as a problem, its solver settings checked and its
    problem discretised once (which refuses geometric nonsense such as an
    obstacle narrower than the contact zone), all before anything runs.
    """
    from elastoplast.fem.discretize import discretize

    base_dir = Path(base_dir)
    if not isinstance(data, Mapping):
        raise InputError("campaign", f"must be a table, got {data!r}")
    unknown = sorted(set(data) - CASE_SECTIONS - {"campaign", "sweep"})
    if unknown:
        raise InputError(unknown[0], f"unknown section (allowed: {sorted(CASE_SECTIONS | {'campaign', 'sweep'})})")
    head = data.get("campaign", {})
    if not isinstance(head, Mapping) or set(head) - {"name", "problem"}:
        raise InputError("campaign", f"allowed keys are 'name' and 'problem', got {head!r}")
    name = head.get("name", name)
    if not isinstance(name, str) or not 0 < len(name) <= MAX_NAME:
        got = f"{len(name)} characters" if isinstance(name, str) else type(name).__name__
        raise InputError("campaign.name", f"must be a string of 1 to {MAX_NAME} characters, got {got}")
    base: dict = {}
    if "problem" in head:
        problem = as_path(head["problem"], "campaign.problem", "problem file")
        base = read_toml(base_dir / problem, field="campaign.problem")
        _rebase_mesh_file(base, problem.parent)
    for section in CASE_SECTIONS & set(data):
        if not isinstance(data[section], Mapping):
            raise InputError(section, f"must be a table, got {data[section]!r}")
        base[section] = {**base.get(section, {}), **copy.deepcopy(dict(data[section]))}
    axes = _axes(data.get("sweep", {}))

    cases: dict[str, Case] = {}
    meshes: dict[str, dict] = {}  # one copy of each distinct mesh
    checked: dict[str, Any] = {}  # problem id -> its discretisation (the last few, for the checks)
    n_points = 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for values in itertools.product(*axes.values()):
            n_points += 1
            point = dict(zip(axes, values))
            case_data = copy.deepcopy(base)
            for axis, value in point.items():
                _set(case_data, axis, value)
            try:
                method, options = solver_settings(case_data.pop("solver", {}))
                target = adapt_settings(case_data.pop("adapt", None), method)
                problem = problem_from_dict(case_data, base_dir)
                if target is not None and (problem.path is not None or problem.depth_controlled):
                    raise InputError("adapt", "an adaptive target is for Hencky's problem under a force, not a "
                                              "loading path or depth control")
                if target is not None:
                    from elastoplast.adapt.loop import check_adaptable

                    check_adaptable(problem)  # H = 0 cannot be adapted: refused now, not recorded as failed
                inp = resolve(problem, method, options, adapt=target)
                mesh_key = content_hash({}, inp.arrays)
                inp = ResolvedInput(spec=inp.spec, arrays=meshes.setdefault(mesh_key, dict(inp.arrays)))
                problem_id = inp.problem_id
                disc = checked.pop(problem_id, None) or discretize(problem)
                checked[problem_id] = disc
                while len(checked) > 8:  # bounded memory for long sweeps
                    checked.pop(next(iter(checked)))
                opts = method_options(method, options)
                try:
                    check_solvable(disc, method, opts)
                except InputError as exc:  # an option that does not suit the problem: name it as written
                    field = f"solver.{exc.field}" if exc.field in opts.specs() else exc.field
                    raise InputError(field, exc.message) from None
            except InputError as exc:
                raise _blame(exc, point) from None
            case_id = inp.case_id
            cases.setdefault(case_id, Case(params=point, input=inp, case_id=case_id, problem_id=problem_id))
    for message in dict.fromkeys(str(w.message) for w in caught):
        warnings.warn(message, stacklevel=2)
    return Campaign(name=name, axes={a: tuple(v) for a, v in axes.items()}, cases=tuple(cases.values()),
                    n_duplicates=n_points - len(cases))


def _rebase_mesh_file(base: dict, folder: Path) -> None:
    """Make the base problem's relative ``mesh.file`` relative to the campaign's folder
    (it is written relative to the problem file in ``folder``); an inline ``[mesh] file``
    and a ``mesh.file`` axis are relative to the campaign file, where they are written."""
    mesh = base.get("mesh")
    if isinstance(mesh, dict) and isinstance(mesh.get("file"), str) and not Path(mesh["file"]).is_absolute():
        mesh["file"] = str(folder / mesh["file"])


def load_campaign(path: str | Path) -> Campaign:
    """Read and validate a campaign TOML file (see the module docstring)."""
    path = as_path(path, "campaign", "campaign file")
    return campaign_from_dict(read_toml(path, field="campaign", what="campaign file"), path.parent, name=path.stem)


# ----------------------------------------------------------------------------
# running on Dask
# ----------------------------------------------------------------------------


def machine_cores() -> int:
    """Cores this process may use (the affinity mask, not the host's total)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


#: most local workers per core (each is a process holding its own problems)
MAX_WORKERS_PER_CORE = 4
_ADDRESS = re.compile(r"^((tcp|tls|inproc|ucx|ws|wss)://)?(\[[0-9a-fA-F:]+\]|[A-Za-z0-9_.-]+)(:\d{1,5})?/?$")


def check_cluster(scheduler: str | None, n_workers: int | None) -> None:
    """Refuse a scheduler address that cannot be one and a local cluster size
    that is not a positive number of processes this machine can hold."""
    if scheduler is not None:
        m = _ADDRESS.match(scheduler.strip()) if isinstance(scheduler, str) else None
        if m is None or (m.group(4) and not 0 < int(m.group(4)[1:]) < 65536):
            raise InputError("scheduler", f"{scheduler!r} is not a scheduler address (e.g. tcp://127.0.0.1:8786)")
        if not m.group(4) and m.group(2) in (None, "tcp", "tls"):
            raise InputError("scheduler", f"{scheduler!r} names no port (e.g. tcp://{m.group(3)}:8786)")
        if n_workers is not None:
            raise InputError("workers", "applies to the local cluster only, not with a scheduler address")
    if n_workers is not None:
        most = MAX_WORKERS_PER_CORE * machine_cores()
        if isinstance(n_workers, bool) or not isinstance(n_workers, int) or not 1 <= n_workers <= most:
            raise InputError("workers", f"must be an integer from 1 to {most} ({MAX_WORKERS_PER_CORE} per core), "
                                        f"got {n_workers!r}")


def _probe(scheduler: str) -> None:
    """Fail at once when nothing listens at a TCP address (Dask would retry for its whole timeout)."""
    import socket

    rest = scheduler.strip().split("://", 1)[-1].rstrip("/")
    if scheduler.startswith(("tcp://", "tls://")) or "://" not in scheduler:
        host, _, port = rest.rpartition(":")
        if host and port.isdigit():
            try:
                socket.create_connection((host.strip("[]"), int(port)), timeout=5.0).close()
            except OSError as exc:
                raise InputError("scheduler", f"cannot connect to {scheduler}: {exc.strerror or exc}") from None


@contextmanager
def dask_client(scheduler: str | None = None, n_workers: int | None = None) -> Iterator[Any]:
    """A client of the cluster at ``scheduler``, or of a local cluster with one
    single-threaded worker process per core (``n_workers`` to override)."""
    from distributed import Client, LocalCluster

    check_cluster(scheduler, n_workers)
    if scheduler:
        _probe(scheduler)
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as exc:  # ValueError: an address distributed cannot parse
            raise InputError("scheduler", f"cannot connect to {scheduler}: {exc}") from None
        with client:
            yield client
        return
    n = n_workers or machine_cores()
    # loopback only; no dashboard, and the scheduler's HTTP routes on a free port
    with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None,
                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}, silence_logs=logging.CRITICAL) as cluster, \
            Client(cluster) as client:
        yield client


def run_case(spec: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> dict[str, Any]:
    """Worker task: rebuild, discretise and solve one case.

    Returns ``{"solution", "summary", "vtu", "worker"}`` (the VTU as bytes so
    that workers need no shared file system), or ``{"error", "traceback",
    "worker"}`` if anything raised.
    """
    from elastoplast.studies.loading_path import depth_case, path_case
    from elastoplast.studies.results import write_files
    from elastoplast.fem.discretize import discretize
    from elastoplast.solvers.registry import solve

    worker = _worker_address()
    try:
        problem = rebuild_problem(spec, arrays)
        if spec.get("adapt") is not None:
            return {**adaptive_case(problem, spec), "worker": worker}
        if problem.path is not None or problem.displacement_path is not None:  # every step, the path's summary
            return {**path_case(problem, spec), "worker": worker}
        if problem.displacement is not None:  # depth control: the force found
            return {**depth_case(problem, spec), "worker": worker}
        disc = discretize(problem)
        sol = solve(disc, spec["method"], **spec["options"])
        with tempfile.TemporaryDirectory(prefix="elastoplast-case-") as tmp:
            data = write_files(Path(tmp), disc, sol)
            vtu = (Path(tmp) / "solution.vtu").read_bytes()
        return {"solution": sol, "summary": data, "vtu": vtu, "worker": worker}
    except Exception as exc:  # recorded in the store; the campaign goes on
        return {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc(), "worker": worker}


def adaptive_case(problem, spec: Mapping[str, Any]) -> dict[str, Any]:
    """Run a case with an adaptive target: :func:`~elastoplast.adapt.loop.adapt` from the
    case's mesh with its method, then the final mesh's solution, summary (with the
    bounds and the U bracket) and VTU, the final mesh (``adapted.msh``) and the
    table of steps (``adapt.json``). The stored status is ``converged`` when the
    target was reached with certified bounds, else the budget that stopped it."""
    import dataclasses

    from elastoplast.adapt.loop import adapt
    from elastoplast.adapt.records import AdaptOptions
    from elastoplast.bounds.bracket import gap_fields
    from elastoplast.certificate.solution import Status
    from elastoplast.studies.results import write_files
    from elastoplast.io.output import json_text
    from elastoplast.mesh.base import write_mesh

    options = AdaptOptions.build({**spec["adapt"], "method": spec["method"]})
    run = adapt(problem, options)
    final, b = run.final, run.bounds
    reached = run.reached(options.rtol)
    status = Status.CONVERGED if reached else (Status.TIME_LIMIT if "time_limit" in run.reason else Status.MAX_ITERATIONS)
    sol = dataclasses.replace(run.solution, status=status, message=f"adapt: {run.reason}; {run.solution.message}")
    bounds = {**b.as_dict(), **run.bracket.as_dict(), "U_lower": final.U_lower, "U_upper": final.U_upper, "final_elements": final.n_elements,
              "adapt_steps": len(run.steps), "adapt_reason": run.reason}
    with tempfile.TemporaryDirectory(prefix="elastoplast-case-") as tmp:
        data = write_files(Path(tmp), run.disc, sol, extra=bounds, **gap_fields(run.disc, b))
        vtu = (Path(tmp) / "solution.vtu").read_bytes()
        write_mesh(Path(tmp) / "adapted.msh", run.disc.mesh)
        files = {"adapted.msh": (Path(tmp) / "adapted.msh").read_bytes(),
                 "adapt.json": json_text({"reason": run.reason, "steps": [s.as_dict() for s in run.steps]}).encode()}
    return {"solution": sol, "summary": data, "vtu": vtu, "files": files, "bounds": bounds}


#: a problem small enough to solve in milliseconds, to warm each worker up
WARM_UP_PROBLEM = {
    "mesh": {"generator": "rectangle", "size": [8.0, 4.0], "divisions": [8, 2], "contact_radius": 2.0},
    "material": {"E": 200000.0, "nu": 0.3, "yield_stress": 1200.0, "hardening": 10000.0},
    "obstacle": {"shape": "cylinder", "radius": 40.0},
    "load": {"force": 100.0},
}


def warm_up(methods: Sequence[str]) -> None:
    """Solve :data:`WARM_UP_PROBLEM` by each method once (run on every worker), so
    that no case's timings include a solver's first imports and compilation.
    Failures are left to the real cases to report."""
    from elastoplast.fem.discretize import discretize
    from elastoplast.solvers.registry import solve

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            disc = discretize(problem_from_dict(WARM_UP_PROBLEM))
        except InputError:  # pragma: no cover - the problem above is valid
            return
        for method in methods:
            try:
                solve(disc, method)
            except Exception:
                pass


def _worker_address() -> str | None:
    from distributed import get_worker

    try:
        return get_worker().address
    except ValueError:  # called outside a Dask worker
        return None


def _progress(total: int, desc: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, unit="case", disable=not enabled, file=sys.stderr, dynamic_ncols=True)


def _failed(out: Mapping[str, Any]) -> bool:
    """Whether a task result (of :func:`run_case` or :func:`compare_problem`) is not a converged solve."""
    if "error" in out:
        return True
    return out["status"] != "converged" if "status" in out else not out["solution"].converged


def recording_warnings(fn, *args) -> dict[str, Any]:
    """The worker side of :func:`gather_results`: ``fn(*args)`` with its warnings recorded
    instead of printed (a worker process prints them raw on the terminal, numpy's once per
    array operation); the result gains ``"warnings"``, each distinct ``(category, text)``
    once, which :func:`gather_results` warns again in the calling process."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = fn(*args)
    said = dict.fromkeys((w.category.__name__, str(w.message)) for w in caught)
    return {**out, "warnings": list(said)}


def gather_results(client: Any, tasks: Mapping[str, tuple], desc: str, progress: bool) -> Iterator[tuple[str, dict]]:
    """Warm the workers up, submit ``{key: (fn, spec, *args)}`` and yield
    ``(key, result)`` as tasks finish; a task whose worker died yields an error
    result instead."""
    from distributed import as_completed

    try:
        client.run(warm_up, sorted({task[1]["method"] for task in tasks.values()}))
    except Exception:  # a worker lost while warming up (a plug-in that ends its process): the cases say so
        pass
    futures = {client.submit(recording_warnings, *task, key=key, pure=False): key for key, task in tasks.items()}
    failed = 0
    with _progress(len(futures), desc, progress) as bar:
        for fut in as_completed(futures):
            try:
                out = fut.result()
            except Exception as exc:  # a lost worker, a cancelled task
                out = {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
            fut.release()
            for category, text in out.pop("warnings", ()):  # said here, where the command's rules apply
                warnings.warn(text, RuntimeWarning if category == "RuntimeWarning" else UserWarning, stacklevel=2)
            failed += _failed(out)
            bar.update(1)
            bar.set_postfix(failed=failed)
            yield futures[fut], out


@dataclass(frozen=True)
class CampaignRun:
    """What :func:`run_campaign` did: case ids skipped (already stored) and run,
    with the status each run ended in (``error`` when it raised)."""

    store: Path
    skipped: tuple[str, ...]
    statuses: Mapping[str, str] = field(default_factory=dict)

    @property
    def failed(self) -> dict[str, str]:
        return {k: v for k, v in self.statuses.items() if v != "converged"}


def run_campaign(campaign: Campaign, out: str | Path, *, scheduler: str | None = None, client: Any = None,
                 n_workers: int | None = None, progress: bool = True, retry_failed: bool = False) -> CampaignRun:
    """Run the cases of ``campaign`` that ``out`` does not hold yet and store each.

    Skipped: every stored case except those whose run raised (``error``: a crash
    or a lost worker, worth retrying); ``retry_failed`` also re-runs those the
    solver did not solve. ``client`` (a ``distributed.Client``) wins over
    ``scheduler``; without both a local cluster is started.
    """
    if client is None:
        check_cluster(scheduler, n_workers)
    with path_errors(out, "out"):  # a name too long for the file system
        store = Store(out)
        created = not store.path.exists()
    try:
        return _run(campaign, store, scheduler, client, n_workers, progress, retry_failed)
    except InputError:  # e.g. no scheduler at the address, a full disk: leave no empty store behind
        if created and _holds_nothing(store) and {p.name for p in store.path.iterdir()} <= STORE_FILES:
            shutil.rmtree(store.path, ignore_errors=True)
        raise


def _holds_nothing(store: Store) -> bool:
    """No case in a store this run created (an index it could not write holds none: a full
    disk's error, not the index's, is the one to report)."""
    try:
        return not store.rows()
    except InputError:
        return True


def _run(campaign: Campaign, store: Store, scheduler: str | None, client: Any, n_workers: int | None,
         progress: bool, retry_failed: bool) -> CampaignRun:
    with store.writer():
        keep = {r["id"]: r["status"] for r in store.rows()}
        keep = {k: s for k, s in keep.items() if s != ERROR and not (retry_failed and s != "converged")}
        todo = {c.case_id: c for c in campaign.cases if c.case_id not in keep}
        skipped = tuple(c.case_id for c in campaign.cases if c.case_id in keep)
        statuses: dict[str, str] = {}
        if not todo:
            return CampaignRun(store=store.path, skipped=skipped)
        tasks = {f"elastoplast-case-{cid}": (run_case, dict(c.input.spec), dict(c.input.arrays)) for cid, c in todo.items()}
        with cluster_client(client, scheduler, n_workers) as cl:
            for key, result in gather_results(cl, tasks, campaign.name, progress):
                case = todo[key.removeprefix("elastoplast-case-")]
                record = case_record(case.input, case.params, campaign.name, **result)
                store.add(record)
                statuses[case.case_id] = record.row["status"]
    return CampaignRun(store=store.path, skipped=skipped, statuses=statuses)


@contextmanager
def cluster_client(client: Any, scheduler: str | None, n_workers: int | None) -> Iterator[Any]:
    if client is not None:
        yield client
        return
    with dask_client(scheduler, n_workers) as cl:
        yield cl
