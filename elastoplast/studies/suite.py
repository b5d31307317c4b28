"""Suites (``elastoplast compare SUITE_DIR --method M1 --method M2 ...``): every method on every
problem file of a folder (a suite of instances), each answer certified at one
tolerance, and the methods compared by performance profiles and shifted geometric
means of their times (:mod:`elastoplast.studies.profiles`).

An instance counts as solved by a method only when its answer is ``converged``: the
certificate's every relative KKT residual at most ``--tol`` (in the user's units as well).
The time is the wall-clock time of the solve (``ep.solve``: the method, its
certificate and the small-strain check; not reading and discretising the problem,
which every method shares). A failure (any other status, an error, a refusal such as
a conic method on a mesh beyond its size limit) counts at the time limit in the
shifted geometric mean, or, without one, at a stated penalty: twice the longest time
any method took to solve any instance.
"""

from __future__ import annotations

import math
import sys
import time
import traceback
from pathlib import Path
from typing import Any, Mapping, Sequence

from elastoplast.studies.profiles import (
    fraction_solved,
    instances_of,
    performance_profile,
    profile_taus,
    shifted_geometric_mean,
)
from elastoplast.errors import InputError

#: the status of an answer certified at the tolerance
SOLVED = "converged"
#: the status of a run that raised (the message says what), and of one refused before any work
ERROR, REFUSED = "error", "refused"
#: the τ at which profile.md tabulates the profiles
TABLE_TAUS = (1.0, 2.0, 4.0, 10.0, 100.0)
#: the shift of the shifted geometric mean, seconds
SHIFT = 1.0


def is_suite_dir(path: str | Path) -> bool:
    """A folder of problem files: a directory with ``*.toml`` in it and no
    ``index.sqlite`` (which would make it a campaign store)."""
    p = Path(path)
    try:
        return p.is_dir() and not (p / "index.sqlite").exists() and any(p.glob("*.toml"))
    except (OSError, ValueError):  # a name too long, a loop: not a suite; the store's own checks name the error
        return False


def suite_instances(suite_dir: str | Path) -> dict[str, Path]:
    """``{name: path}`` of the problem files of a suite folder (name: the file's stem), sorted by name."""
    p = Path(suite_dir)
    files = sorted(p.glob("*.toml")) if p.is_dir() else []
    if not files:
        raise InputError("suite_dir", f"{p} is no folder of problem files (*.toml)")
    return {f.stem: f for f in files}


def suite_options(methods: Sequence[str], tol: float, time_limit: float | None,
                  options: Mapping[str, Any] | None = None) -> dict[str, dict[str, Any]]:
    """``{method: options}``, checked: ``tol`` and ``time_limit`` for every method, and
    each further option for the methods that have it (an option none has is refused)."""
    from elastoplast.solvers.registry import get_method, method_options

    if not methods:
        raise InputError("methods", "give at least one method")
    if len(set(methods)) != len(methods):
        raise InputError("methods", f"a method is named twice: {list(methods)}")
    options = dict(options or {})
    out, used = {}, set()
    for m in methods:
        specs = get_method(m, "methods").options.specs()
        own = {k: v for k, v in options.items() if k in specs}
        used |= own.keys()
        given = {**own, "tol": tol, "time_limit": time_limit, "progress": False}
        method_options(m, given)  # checked now, before any work
        out[m] = given
    unused = sorted(set(options) - used)
    if unused:
        raise InputError(unused[0], f"not an option of any of {list(methods)}")
    return out


def run_instance(spec: Mapping[str, Any]) -> dict[str, Any]:
    """Solve one instance by one method: ``spec`` holds ``method``, ``options`` (a
    mapping), ``problem`` (the problem file's path) and ``name``. Never raises for the
    solve: an error is a record with status ``error`` (or ``refused``, for input the
    method turns down before any work, such as a mesh beyond its size)."""
    from elastoplast.fem.discretize import discretize
    from elastoplast.problem.definition import load_problem
    from elastoplast.solvers.registry import solve

    rec: dict[str, Any] = {"instance": spec["name"], "method": spec["method"]}
    try:
        disc = discretize(load_problem(spec["problem"]))
    except Exception as exc:
        return {**rec, "status": ERROR, "message": f"reading the problem: {type(exc).__name__}: {exc}"}
    rec.update(dim=disc.dim, n_elements=disc.n_elements)
    t0 = time.perf_counter()
    try:
        if disc.problem.path is not None:  # a loading path: the time of all its steps, the worst KKT of them
            return {**rec, **_run_path(disc, spec), "time_s": time.perf_counter() - t0}
        sol = solve(disc, spec["method"], **spec["options"])
    except InputError as exc:
        return {**rec, "status": REFUSED, "message": str(exc), "time_s": time.perf_counter() - t0}
    except Exception as exc:
        return {**rec, "status": ERROR, "message": f"{type(exc).__name__}: {exc}", "time_s": time.perf_counter() - t0,
                "traceback": traceback.format_exc()}
    wall = time.perf_counter() - t0
    return {**rec, "status": sol.status.value, "message": sol.message, "time_s": wall, "solver_time_s": sol.time_s,
            "kkt_worst": sol.kkt.worst, "U": sol.U, "iterations": sol.iterations}


def _run_path(disc, spec: Mapping[str, Any]) -> dict[str, Any]:
    """An instance with a loading path: solved when every step converged; its KKT
    residual is the worst of the steps', its U the last step's."""
    from elastoplast.io.loading_path import path_status
    from elastoplast.solvers.path import solve_path

    result = solve_path(disc, disc.problem.path, spec["method"], **spec["options"])
    status, message = path_status(result)
    return {"status": status.value, "message": message, "solver_time_s": result.time_s,
            "kkt_worst": max(s.solution.kkt.worst for s in result.steps), "U": result.steps[-1].U,
            "iterations": sum(s.solution.iterations for s in result.steps), "n_steps": len(result.forces)}


def is_solved(record: Mapping[str, Any], tol: float) -> bool:
    """Solved: status ``converged`` with the certificate's worst residual at most ``tol``."""
    worst = record.get("kkt_worst")
    return (record.get("status") == SOLVED and worst is not None and math.isfinite(worst) and worst <= tol
            and record.get("time_s") is not None)


def profile_record(records: Sequence[Mapping[str, Any]], tol: float, time_limit: float | None,
                   failure_time: float | None = None, suite: str = "") -> dict[str, Any]:
    """Everything ``profile.json`` holds, from one record per (method, instance) run
    (:func:`run_instance`'s, with possibly more keys): times (None where not solved),
    statuses, the profile over :func:`profile_taus`, the shifted geometric means, the
    fraction solved and the failures. ``failure_time``: the time a failure counts for;
    default the time limit, else twice the longest time of a solved run (at least 1 s)."""
    methods = list(dict.fromkeys(r["method"] for r in records))
    times: dict[str, dict[str, float | None]] = {m: {} for m in methods}
    statuses: dict[str, dict[str, str]] = {m: {} for m in methods}
    sizes: dict[str, dict[str, Any]] = {}
    failures: dict[str, list[dict[str, Any]]] = {m: [] for m in methods}
    for r in records:
        m, p = r["method"], r["instance"]
        ok = is_solved(r, tol)
        times[m][p] = float(r["time_s"]) if ok else None
        statuses[m][p] = r["status"]
        if r.get("n_elements") is not None:
            sizes[p] = {"dim": r.get("dim"), "n_elements": r["n_elements"]}
        if not ok:
            failures[m].append({"instance": p, "status": r["status"], "message": r.get("message", "")})
    solved_times = [t for per in times.values() for t in per.values() if t is not None]
    if failure_time is None:
        if time_limit is not None:
            failure_time, rule = float(time_limit), "the time limit"
        else:
            failure_time = max(2.0 * max(solved_times, default=0.5), 1.0)
            rule = "twice the longest solved time (at least 1 s): no time limit was set"
    else:
        rule = "a stated penalty"
    taus = profile_taus(times)
    return {
        "suite": suite, "tol": tol, "time_limit": time_limit, "shift_s": SHIFT,
        "failure_time_s": failure_time, "failure_rule": rule, "methods": methods,
        "instances": {p: sizes.get(p, {}) for p in instances_of(times)},
        "times": times, "statuses": statuses, "taus": taus, "profile": performance_profile(times, taus),
        "profile_at": {str(t): {m: v[i] for m, v in performance_profile(times, TABLE_TAUS).items()}
                       for i, t in enumerate(TABLE_TAUS)},
        "shifted_geometric_mean_s": shifted_geometric_mean(times, SHIFT, failure_time=failure_time),
        "fraction_solved": fraction_solved(times), "failures": failures,
    }


def _cell(record: Mapping[str, Any], m: str, p: str) -> str:
    t, status = record["times"][m].get(p), record["statuses"][m].get(p)
    if status is None:
        return "–"
    return f"{t:.3g}" if t is not None else f"✗ {status}"


def profile_markdown(record: Mapping[str, Any]) -> str:
    """``profile.md``: times per instance and method, then per method the fraction
    solved, the shifted geometric mean and the profile at a few τ, then the failures."""
    methods, names = record["methods"], list(record["instances"])
    lines = [f"Tolerance: every relative KKT residual <= {record['tol']:g}; time limit "
             f"{'none' if record['time_limit'] is None else format(record['time_limit'], 'g') + ' s'}; a failure "
             f"counts {record['failure_time_s']:.4g} s ({record['failure_rule']}); shift {record['shift_s']:g} s.", "",
             "Wall-clock seconds of each solve (✗: not solved to the tolerance, with the status).", "",
             "| instance | dim | elements | " + " | ".join(methods) + " |", "|" + "---|" * (3 + len(methods))]
    for p in names:
        size = record["instances"][p]
        elements = f"{size['n_elements']:,}" if size.get("n_elements") is not None else "–"
        lines.append(f"| {p} | {size.get('dim') or '–'} | {elements} | "
                     + " | ".join(_cell(record, m, p) for m in methods) + " |")
    head = ["method", "solved", "shifted geom. mean [s]"] + [f"ρ(τ={t:g})" for t in TABLE_TAUS]
    lines += ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    n = len(names)
    for m in methods:
        solved = sum(t is not None for t in record["times"][m].values())
        at = [record["profile_at"][str(t)][m] for t in TABLE_TAUS]
        lines.append(f"| {m} | {solved}/{n} ({100 * record['fraction_solved'][m]:.0f}%) | "
                     f"{record['shifted_geometric_mean_s'][m]:.3g} | " + " | ".join(f"{v:.2f}" for v in at) + " |")
    lines += ["", "ρ(τ): the fraction of all instances the method solved within a factor τ of the fastest method "
                  "on that instance (Dolan & Moré 2002)."]
    fails = [(m, f) for m in methods for f in record["failures"][m]]
    if fails:
        lines += ["", "Failures:", ""]
        lines += [f"- {m} on {f['instance']}: {f['status']}: {str(f['message'])[:200]}" for m, f in fails]
    return "\n".join(lines) + "\n"


def write_profile(record: Mapping[str, Any], out_dir: str | Path, field: str = "out", title: str = "") -> Path:
    """Write ``profile.png``, ``profile.json`` and ``profile.md`` into ``out_dir``
    (staged: the folder is replaced only when all three are written)."""
    from elastoplast.plots.figures import plot_profile
    from elastoplast.io.output import json_text, staged_output
    from elastoplast.io.store import atomic_write

    heading = title or f"Performance profile of {', '.join(record['methods'])}" + (
        f" on {record['suite']}" if record.get("suite") else "")
    with staged_output(out_dir, field) as tmp:
        atomic_write(tmp / "profile.json", json_text(record).encode())
        atomic_write(tmp / "profile.md", (f"# {heading}\n\n" + profile_markdown(record)).encode())
        plot_profile(record["profile"], tmp / "profile.png", taus=record["taus"],
                     title=f"{len(record['instances'])} instances, KKT ≤ {record['tol']:g}")
    return Path(out_dir)


def check_instances(instances: Mapping[str, Path]) -> None:
    """Read every problem file of a suite before any run, as a campaign checks its cases:
    bad input is refused naming the file and the field (it was timed as a failure), and
    so is depth control, which a suite does not time (its solves are a root search)."""
    import warnings

    from elastoplast.problem.definition import load_problem

    for path in instances.values():
        with warnings.catch_warnings():  # said again by the runs that meet them
            warnings.simplefilter("ignore")
            try:
                problem = load_problem(path)
            except InputError as exc:
                raise InputError(f"{path.name}: {exc.field}", exc.message) from None
        if problem.displacement is not None or problem.displacement_path is not None:
            key = "displacement" if problem.displacement is not None else "displacement_path"
            raise InputError(f"{path.name}: load.{key}", "a suite times solves under a force (load.force, load.path); "
                                                        "depth control is solved by 'elastoplast solve'")


def run_suite(suite_dir: str | Path, methods: Sequence[str], *, out: str | Path, tol: float = 1e-6,
              time_limit: float | None = None, options: Mapping[str, Any] | None = None,
              scheduler: str | None = None, client: Any = None, n_workers: int | None = None,
              progress: bool = True) -> dict[str, Any]:
    """Run every method on every problem file of ``suite_dir`` and write the profile
    into ``out`` (:func:`write_profile`); returns :func:`profile_record`'s record.

    In this process, one run after another (the times undisturbed), unless a Dask
    ``client``, a ``scheduler`` address or ``n_workers`` is given: then on that cluster
    (the machinery of ``elastoplast campaign``; concurrent runs share the machine)."""
    from elastoplast.studies.campaign import check_cluster, cluster_client, gather_results, warm_up
    from elastoplast.io.output import check_output_dir

    per_method = suite_options(methods, tol, time_limit, options)
    instances = suite_instances(suite_dir)
    check_instances(instances)
    check_output_dir(out, "out")
    specs = [{"method": m, "options": per_method[m], "problem": str(path), "name": name}
             for name, path in instances.items() for m in methods]
    records: list[dict[str, Any]] = []
    if client is None and scheduler is None and n_workers is None:
        warm_up(methods)  # no run's time includes a solver's first imports
        for i, spec in enumerate(specs, 1):
            rec = run_instance(spec)
            records.append(rec)
            if progress:
                print(f"[{i}/{len(specs)}] {spec['name']} {spec['method']}: {rec['status']}"
                      + (f", {rec['time_s']:.3g} s" if rec.get("time_s") is not None else ""), file=sys.stderr)
    else:
        if client is None:
            check_cluster(scheduler, n_workers)
        tasks = {f"elastoplast-suite-{i}": (run_instance, spec) for i, spec in enumerate(specs)}
        done: dict[int, dict] = {}
        with cluster_client(client, scheduler, n_workers) as cl:
            for key, result in gather_results(cl, tasks, "suite", progress):
                i = int(key.rsplit("-", 1)[1])
                if "status" not in result:  # a lost worker: gather_results' error record
                    result = {"instance": specs[i]["name"], "method": specs[i]["method"], "status": ERROR,
                              "message": result.get("error", "unknown error")}
                done[i] = result
        records = [done[i] for i in range(len(specs))]
    record = profile_record(records, tol, time_limit, suite=Path(suite_dir).name)
    record["runs"] = records
    write_profile(record, out)
    return record
