"""``elastoplast compare``: the cases of a stored campaign solved again by other methods, their errors against the stored reference, a table and a plot."""

from __future__ import annotations

import json
import math
import statistics
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from elastoplast.studies.campaign import cluster_client, gather_results, check_cluster
from elastoplast.plots.figures import plot_comparison
from elastoplast.errors import InputError, figure
from elastoplast.io.output import check_output_dir, json_text, staged_output
from elastoplast.io.store import ERROR, Store, atomic_write, rebuild_problem, resolve
from elastoplast.solvers.registry import solver_settings


def solution_errors(disc, sol, ref) -> dict[str, float]:
    """Errors of ``sol`` against the reference ``ref`` (both Solutions of ``disc``):

    * ``U_rel = |U - U_ref| / |U_ref|``;
    * ``sigma_rel = sqrt([s - s_ref, s - s_ref] / [s_ref, s_ref])`` in the energy
      inner product of docs/math.md (``s = (sigma, xi)``; the xi part is
      dropped when H = 0);
    * ``time_ratio = time / time_ref`` (each solver's own ``timings['total']``).
    """
    from elastoplast.certificate.kkt import energy_norm_sq

    ref_norm = energy_norm_sq(disc, ref.sigma, ref.xi)
    diff = energy_norm_sq(disc, sol.sigma - ref.sigma, sol.xi - ref.xi)
    tiny = np.finfo(float).tiny
    return {
        "U_rel": abs(sol.U - ref.U) / max(abs(ref.U), tiny),
        "sigma_rel": math.sqrt(diff / max(ref_norm, tiny)),
        "time_ratio": sol.time_s / max(ref.time_s, tiny),
    }


def compare_problem(spec: Mapping[str, Any], arrays: Mapping[str, np.ndarray], refs: Sequence[tuple[str, Any]]) -> dict:
    """Worker task: solve one stored problem by ``spec['method']`` and measure it
    against each reference ``(case_id, Solution)`` of that problem."""
    from elastoplast.fem.discretize import discretize
    from elastoplast.solvers.registry import solve

    steps = None
    try:
        disc = discretize(rebuild_problem(spec, arrays))
        if spec.get("path") is not None or spec.get("displacement_path") is not None:  # every step, compared
            from elastoplast.io.loading_path import path_solution  # step by step in compare()
            from elastoplast.solvers.depth import solve_depth_path
            from elastoplast.solvers.path import solve_path

            if spec.get("path") is not None:
                result = solve_path(disc, spec["path"], spec["method"], **spec["options"])
            else:
                result, _ = solve_depth_path(disc, spec["displacement_path"], spec["method"], **spec["options"])
            sol = path_solution(result)
            steps = [{"step": st.index, "force": st.force, "U": st.U, "kkt_worst": st.solution.kkt.worst,
                      "status": st.status.value} for st in result.steps]
        elif spec.get("displacement") is not None:  # depth control: the solve at the force found
            from elastoplast.solvers.depth import solve_depth

            found = solve_depth(disc, spec["displacement"], spec["method"], **spec["options"])
            if found.solution is None:
                raise InputError("load.displacement", "lift-off: F = 0, no contact and no solution to compare")
            sol, disc = found.solution, disc.with_force(found.force)
        else:
            sol = solve(disc, spec["method"], **spec["options"])
    except Exception as exc:
        return {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()}
    return {
        "status": sol.status.value, "message": sol.message, "U": sol.U,
        "kkt_worst": sol.kkt.worst if steps is None else max(st["kkt_worst"] for st in steps),
        "iterations": sol.iterations, "time_s": sol.time_s,
        "errors": {case_id: solution_errors(disc, sol, ref) for case_id, ref in refs},
        **({} if steps is None else {"steps": steps}),
    }


def step_errors(steps: Sequence[Mapping[str, Any]], ref_path: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """A path's steps against the reference's (``summary.json``'s ``"path"``), step by
    step: both U, ``U_rel = |U - U_ref| / |U_ref|``, both KKT worst residuals and
    statuses; only the steps both ran."""
    tiny = np.finfo(float).tiny
    return [{"step": st["step"], "force": st["force"], "U_ref": ref["U"], "U": st["U"],
             "U_rel": abs(st["U"] - ref["U"]) / max(abs(ref["U"]), tiny), "kkt_worst_ref": ref["kkt_worst"],
             "kkt_worst": st["kkt_worst"], "status_ref": ref["status"], "status": st["status"]}
            for st, ref in zip(steps, ref_path)]


@dataclass(frozen=True)
class Comparison:
    """Per reference case (``rows``) and overall (``summary``) errors of ``method``."""

    method: str
    rows: tuple[dict[str, Any], ...]
    summary: Mapping[str, Any]

    def markdown(self) -> str:
        head = ["case", "parameters", "reference", "status", "U ref", "U", "U rel. err.", "σ energy rel. err.",
                "KKT worst", "t ref [s]", "t [s]", "time ratio"]
        lines = [f"# {self.method} against the stored references", "",
                 "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in self.rows:
            cells = [r["case"][:12], _params_text(r["params"]), r["reference_method"], r["status"],
                     _g(r["U_ref"]), _g(r.get("U")), _e(r.get("U_rel")), _e(r.get("sigma_rel")),
                     _e(r.get("kkt_worst")), _g(r["time_ref"]), _g(r.get("time_s")), _g(r.get("time_ratio"))]
            lines.append("| " + " | ".join(cells) + " |")
        lines += _step_table(self.rows)
        s = self.summary
        lines += ["", f"{s['n_cases']} reference case(s), {s['n_problems']} problem(s); {_method_runs(s)}."]
        if s["n_compared"]:
            lines += [f"- U relative error: max {_e(s['U_rel_max'])}, median {_e(s['U_rel_median'])}",
                      f"- σ energy relative error: max {_e(s['sigma_rel_max'])}, median {_e(s['sigma_rel_median'])}",
                      f"- time ratio ({self.method} / reference): median {_g(s['time_ratio_median'])}, "
                      f"geometric mean {_g(s['time_ratio_geomean'])}"]
        return "\n".join(lines) + "\n"


def _step_table(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The loading paths step by step (for a path, the table's U error is the largest over its steps)."""
    paths = [r for r in rows if r.get("steps")]
    if not paths:
        return []
    head = ["case", "step", "F", "U ref", "U", "U rel. err.", "KKT ref", "KKT", "status"]
    lines = ["", "Loading paths, step by step (a path's U rel. err. above is the largest of its steps):", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in paths:
        lines += [f"| {r['case'][:12]} | {st['step']} | {_g(st['force'])} | {_g(st['U_ref'])} | {_g(st['U'])} | "
                  f"{_e(st['U_rel'])} | {_e(st['kkt_worst_ref'])} | {_e(st['kkt_worst'])} | {st['status']} |"
                  for st in r["steps"]]
    return lines


def _method_runs(s: Mapping[str, Any]) -> str:
    return f"{s['n_converged']} converged, {s['n_not_converged']} not converged, {s['n_errors']} raised"


def _g(x: Any) -> str:
    return "–" if x is None else figure(x, ".4g")


def _e(x: Any) -> str:
    return "–" if x is None else figure(x, ".2e")


def _params_text(params: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={json.dumps(v)}" for k, v in params.items()) or "–"


def _summarise(rows: Sequence[dict[str, Any]], n_problems: int) -> dict[str, Any]:
    ok = [r for r in rows if r["status"] == "converged"]
    out: dict[str, Any] = {
        "n_cases": len(rows), "n_problems": n_problems, "n_compared": len(ok),
        "n_converged": sum(r["status"] == "converged" for r in rows),
        "n_not_converged": sum(r["status"] not in ("converged", ERROR) for r in rows),
        "n_errors": sum(r["status"] == ERROR for r in rows),
    }
    if ok:
        for key in ("U_rel", "sigma_rel"):
            vals = [r[key] for r in ok]
            out[f"{key}_max"], out[f"{key}_median"] = max(vals), statistics.median(vals)
        ratios = [r["time_ratio"] for r in ok]
        out["time_ratio_median"] = statistics.median(ratios)
        out["time_ratio_geomean"] = math.exp(statistics.fmean(math.log(max(x, 1e-300)) for x in ratios))
    return out


def compare(store_dir: str | Path, method: str, *, options: Mapping[str, Any] | None = None,
            reference_method: str | None = None, out: str | Path | None = None, scheduler: str | None = None,
            client: Any = None, n_workers: int | None = None, progress: bool = True) -> Comparison:
    """Run ``method`` on every converged stored case (its reference) and report.

    Each distinct problem is solved once and measured against every reference of
    it. Writes ``report.md``, ``compare.png`` and ``compare.json`` into ``out``
    (default ``DIR/compare-<method>``) and returns the :class:`Comparison`.
    """
    if client is None:
        check_cluster(scheduler, n_workers)
    store = Store(store_dir)
    if not store.exists():
        raise InputError("store", f"no campaign store at {store.path} (no index.sqlite)")
    method, options = solver_settings({"method": method, **(options or {})}, prefix="compare")
    out_dir = Path(out) if out is not None else store.path / f"compare-{method}"
    check_output_dir(out_dir, "out")  # before any work
    where, params = "status = 'converged'", ()
    if reference_method is not None:
        where, params = where + " AND method = ?", (reference_method,)
    rows = store.rows(where, params)
    refs = [r for r in rows if r.get("final_elements") is None]  # adaptive cases: own meshes
    if not refs:
        raise InputError("reference_method" if reference_method else "store", f"no converged reference case in {store.path}"
                         + (f" solved by {reference_method!r}" if reference_method else "")
                         + (f" ({len(rows)} adaptive case(s), on meshes of their own, are not compared)" if rows else ""))
    by_problem: dict[str, list[dict]] = {}
    for row in refs:
        by_problem.setdefault(row["problem_id"], []).append(row)
    tasks = {}
    for problem_id, rows in by_problem.items():
        inp = store.load_input(rows[0]["id"])
        spec = {**resolve(rebuild_problem(inp.spec, inp.arrays), method, options).spec}
        solutions = [(r["id"], store.load_solution(r["id"])) for r in rows]
        tasks[f"elastoplast-compare-{method}-{problem_id}"] = (compare_problem, spec, inp.arrays, solutions)
    results: dict[str, dict] = {}
    with cluster_client(client, scheduler, n_workers) as cl:
        for key, result in gather_results(cl, tasks, f"compare {method}", progress):
            results[key.rsplit("-", 1)[1]] = result
    rows_out = []
    for row in refs:
        res = results[row["problem_id"]]
        entry = {"case": row["id"], "params": json.loads(row["params"]), "reference_method": row["method"],
                 "U_ref": row["U"], "time_ref": row["time_total"]}
        if "error" in res:
            entry.update(status=ERROR, error=res["error"])
        else:
            entry.update(status=res["status"], U=res["U"], kkt_worst=res["kkt_worst"], time_s=res["time_s"],
                         iterations=res["iterations"], message=res["message"], **res["errors"][row["id"]])
            if "steps" in res:  # a path: U_rel is the largest over the steps both ran
                entry["steps"] = step_errors(res["steps"], store.load_path(row["id"]) or [])
                entry["U_rel"] = max([entry["U_rel"], *(st["U_rel"] for st in entry["steps"])])
        rows_out.append(entry)
    comparison = Comparison(method=method, rows=tuple(rows_out), summary=_summarise(rows_out, len(by_problem)))
    with staged_output(out_dir, "out") as tmp:
        atomic_write(tmp / "report.md", comparison.markdown().encode())
        atomic_write(tmp / "compare.json", json_text({"method": method, "options": options, "rows": rows_out,
                                                      "summary": comparison.summary}).encode())
        plot_comparison(comparison, tmp / "compare.png")
    return comparison
