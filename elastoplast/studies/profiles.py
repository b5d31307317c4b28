"""Performance profiles (Dolan & Moré, *Benchmarking optimization software with
performance profiles*, Math. Program. 91, 2002) and shifted geometric means of
solve times: how the optimisation community compares solvers over a suite of
instances. Plain Python, no library.

``times`` is ``{method: {instance: seconds or None}}``; ``None`` (or ``inf``, or a
missing instance) means the method did not solve the instance (not certified at the
tolerance, a time limit, an error). Instances are the union over the methods.

* the performance ratio of method m on instance p is ``r = t[m][p] / min_m' t[m'][p]``
  (``inf`` when m failed on p, and for every method when none solved p);
* the profile of m at τ ≥ 1 is the fraction of the instances with ``r ≤ τ``: at
  τ = 1 the fraction where m was the fastest (ties count for each), for large τ the
  fraction m solved at all;
* the shifted geometric mean is ``exp(mean(log(t + s))) - s`` with shift ``s`` (1 s by
  default: times well under a second weigh little), a failure counted at
  ``failure_time`` (the time limit, or a stated penalty).
"""

from __future__ import annotations

import math
from typing import Iterable, Mapping

Times = Mapping[str, Mapping[str, "float | None"]]


def _solved(t: float | None) -> bool:
    return t is not None and math.isfinite(t)


def instances_of(times: Times) -> list[str]:
    """Every instance any method was run on, in the order first met."""
    seen: dict[str, None] = {}
    for per_method in times.values():
        for name in per_method:
            seen.setdefault(name, None)
    return list(seen)


def performance_ratios(times: Times) -> dict[str, dict[str, float]]:
    """``{method: {instance: r}}``: each time over the best time on that instance,
    ``inf`` where the method failed or no method solved the instance."""
    names = instances_of(times)
    best = {}
    for p in names:
        solved = [float(t[p]) for t in times.values() if _solved(t.get(p))]
        best[p] = min(solved) if solved else math.inf
    out: dict[str, dict[str, float]] = {}
    for m, t in times.items():
        row = {}
        for p in names:
            tp = t.get(p)
            if not _solved(tp) or not math.isfinite(best[p]):
                row[p] = math.inf
            elif best[p] <= 0:  # a zero best time: only the others at zero tie with it
                row[p] = 1.0 if float(tp) <= 0 else math.inf
            else:
                row[p] = float(tp) / best[p]
        out[m] = row
    return out


def performance_profile(times: Times, taus: Iterable[float]) -> dict[str, list[float]]:
    """``{method: [ρ(τ) for τ in taus]}``, ρ(τ) the fraction of all instances on which
    the method's time is within a factor τ of the best method's."""
    taus = [float(x) for x in taus]
    ratios = performance_ratios(times)
    n = len(instances_of(times))
    if n == 0:
        return {m: [0.0] * len(taus) for m in times}
    return {m: [sum(r <= tau for r in row.values()) / n for tau in taus] for m, row in ratios.items()}


def profile_taus(times: Times, margin: float = 2.0) -> list[float]:
    """The τ at which some profile steps (1 and every finite ratio, sorted), then the
    largest of them times ``margin``, where each curve has reached the fraction its
    method solved: drawn as steps ``where='post'`` over these the curves are exact."""
    finite = {r for row in performance_ratios(times).values() for r in row.values() if math.isfinite(r)}
    taus = sorted(finite | {1.0})
    return taus + [taus[-1] * margin]


def shifted_geometric_mean(times: Times, shift: float = 1.0, *, failure_time: float) -> dict[str, float]:
    """``{method: exp(mean_p log(t_p + shift)) - shift}`` over all instances, a failure
    (None, inf, a missing instance) counted as ``failure_time`` seconds."""
    if not (math.isfinite(failure_time) and failure_time > 0):
        raise ValueError(f"failure_time must be a positive number of seconds, got {failure_time!r}")
    if shift < 0:
        raise ValueError(f"shift must be >= 0, got {shift!r}")
    names = instances_of(times)
    out = {}
    for m, t in times.items():
        if not names:
            out[m] = math.nan
            continue
        logs = [math.log((float(t[p]) if _solved(t.get(p)) else failure_time) + shift) for p in names]
        out[m] = math.exp(sum(logs) / len(logs)) - shift
    return out


def fraction_solved(times: Times) -> dict[str, float]:
    """``{method: solved instances / all instances}``: each profile's limit as τ grows."""
    n = len(instances_of(times))
    return {m: (sum(_solved(t.get(p)) for p in instances_of(times)) / n if n else 0.0) for m, t in times.items()}
