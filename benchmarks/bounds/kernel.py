"""Side study: what one ring-element visit of the compiled sweep step costs, in one thread and in two.

    python benchmarks/bounds/kernel.py [--quick] [--out DIR] [--report]

The local bound's sweeps are a compiled Newton step per ring (``kernel.ring_newton``);
their work is one pass over each element of each ring (a *visit*: in 3D every tetrahedron
is visited once per edge, six times per full sweep). Per size of the default 3D problem
(12,288 and 98,304 tetrahedra; ``--quick``: 1,536 and 12,288), in its own process: the P1
solve, then one sweep of the local bound with every call of the step recorded; the recorded
calls are then replayed ``ROUNDS`` times, alternately in one thread (each batch in one call)
and in ``sweeps.KERNEL_THREADS`` threads (``sweeps.in_slices``, as the sweeps run them), each
round from the same tractions. Reported: microseconds per visit (median over the rounds),
and the two-thread gain, the median of the paired ratios one thread / threads.

The control is a compiled dense matrix-vector loop with no shared writes, run once and then
twice at the same time: its gain is what the second core of this machine gives to arithmetic
alone. Writes ``kernel.json`` and ``kernel.md`` beside this file (``--quick``: in
``benchmarks/bounds/quick/``).
"""

from __future__ import annotations

import json
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_child, run_record, shipped_problem  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
STUDY = "kernel"
TITLE = "The compiled ring step: cost per ring-element visit, one thread and two"
PROBLEM = "sphere_block_3d"
SIZES = [(16, 16, 8), (32, 32, 16)]
QUICK = [(8, 8, 4), (16, 16, 8)]
ROUNDS = 5


def record_sweep(disc, sol) -> tuple[list, np.ndarray, int]:
    """The calls of the compiled step in one sweep of the local bound: ``(calls, t, it)``, each call
    ``(m, args)`` with its arguments by reference (the kernel writes only the tractions, the first
    of the group ``args[it]``, and its gains), ``t`` the tractions before the sweep's first call."""
    from elastoplast.bounds.local import sweeps
    from elastoplast.bounds.local.construction import local_lower_bound
    from elastoplast.bounds.local.kernel import ring_newton

    calls, first = [], {}
    it = ring_newton.py_func.__code__.co_varnames.index("field") - 2
    original = sweeps.in_slices

    def recording(kernel, m, args, **slicing):
        if kernel is ring_newton:
            first.setdefault("t", args[it][0].copy())
            calls.append((m, list(args)))
        return original(kernel, m, args, **slicing)

    sweeps.in_slices = recording
    try:
        local_lower_bound(disc, sol, n_sweeps=1, descent=0)
    finally:
        sweeps.in_slices = original
    return calls, first["t"], it


def replay(calls, t0: np.ndarray, it: int, threads: bool) -> float:
    """Seconds in the kernel for one replay of the recorded calls from the tractions ``t0``."""
    from elastoplast.bounds.local import sweeps
    from elastoplast.bounds.local.kernel import ring_newton

    t = t0.copy()
    total = 0.0
    for m, args in calls:
        args = list(args)
        args[it] = (t,) + tuple(args[it][1:])
        args[-1] = np.zeros(m)
        start = time.perf_counter()
        if threads:
            sweeps.in_slices(ring_newton, m, args, least=sweeps.RING_SLICE, per_thread=sweeps.RING_SLICES_PER_THREAD)
        else:
            ring_newton(0, m, *args)
        total += time.perf_counter() - start
    return total


def control_gain(rounds: int = ROUNDS) -> dict:
    """A compiled dense matrix-vector loop (96 x 48, the lift's shape) once, then twice at the same time
    in two threads: ``gain`` = 2 x (one) / (two at once), the median over the rounds."""
    from numba import njit

    @njit(nogil=True, fastmath=True)
    def matvec(n, A, x, y):
        for _ in range(n):
            for r in range(A.shape[0]):
                acc = 0.0
                for c in range(A.shape[1]):
                    acc += A[r, c] * x[c]
                y[r] += 1e-9 * acc

    A, x = np.random.default_rng(0).random((96, 48)), np.ones(48)
    ys = [np.zeros(96), np.zeros(96)]
    matvec(1, A, x, ys[0])
    n = 40000
    ratios = []
    for _ in range(rounds):
        start = time.perf_counter()
        matvec(n, A, x, ys[0])
        one = time.perf_counter() - start
        pair = [threading.Thread(target=matvec, args=(n, A, x, ys[i])) for i in range(2)]
        start = time.perf_counter()
        for th in pair:
            th.start()
        for th in pair:
            th.join()
        ratios.append(2 * one / (time.perf_counter() - start))
    return {"gain": float(np.median(ratios)), "gains": ratios}


def run_one(divisions) -> dict:
    import elastoplast as ep
    from elastoplast.bounds.local import sweeps

    disc = shipped_problem(PROBLEM, divisions)
    sol = ep.solve(disc, "newton")
    calls, t0, it = record_sweep(disc, sol)
    visits = int(sum(args[1].sum() for _, args in calls))
    replay(calls, t0, it, threads=False)  # the compiled code is loaded; the first pass of the data warm
    one, many = [], []
    for _ in range(ROUNDS):
        one.append(replay(calls, t0, it, threads=False))
        many.append(replay(calls, t0, it, threads=True))
    one, many = np.array(one), np.array(many)
    return {"n_elements": int(disc.n_elements), "rings": int(sum(m for m, _ in calls)), "visits": visits,
            "batches": len(calls), "threads": sweeps.KERNEL_THREADS,
            "us_per_visit_one": 1e6 * float(np.median(one)) / visits,
            "us_per_visit_threads": 1e6 * float(np.median(many)) / visits,
            "thread_gain": float(np.median(one / many)), "one_s": one.tolist(), "threads_s": many.tolist(),
            "control": control_gain()}


def report(results: dict) -> str:
    lines = ["Each size in its own process; one sweep's recorded calls of the compiled step replayed "
             f"{ROUNDS} times in one thread and in threads, alternately; µs per ring-element visit (median); "
             "`gain` the median of the paired ratios one thread / threads; `control gain` a compiled "
             "matrix-vector loop run twice at once in two threads against once (2 x one / both).",
             "",
             "| tetrahedra | rings | visits | threads | µs/visit, one thread | µs/visit, threads | gain | "
             "control gain |",
             "|---|---|---|---|---|---|---|---|"]
    for r in results["cases"]:
        if "error" in r:
            lines.append(f"| {r.get('divisions')} | error: {r['error']} |")
            continue
        lines.append(f"| {r['n_elements']:,} | {r['rings']:,} | {r['visits']:,} | {r['threads']} | "
                     f"{r['us_per_visit_one']:.1f} | {r['us_per_visit_threads']:.1f} | {r['thread_gain']:.2f} | "
                     f"{r['control']['gain']:.2f} |")
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path) -> dict:
    results = {"cases": []}
    for div in (QUICK if mode == "quick" else SIZES):
        case = run_child(__file__, list(div), cwd=ROOT)
        case["divisions"] = list(div)
        results["cases"].append(case)
        print(json.dumps({k: v for k, v in case.items() if not k.endswith("_s")}), flush=True)
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "1,536 and 12,288 tetrahedra", HERE, TITLE, "compiled ring step", measure,
                      report, argv=argv, study=STUDY, child=run_one)


if __name__ == "__main__":
    sys.exit(main())
