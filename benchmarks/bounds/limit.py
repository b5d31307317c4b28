"""Side study: the limit-load bracket F_lower <= F_c <= F_upper on Prandtl's punch (docs/bounds.md).

    python benchmarks/bounds/limit.py [--quick] [--out DIR] [--report]

A rigid flat frictionless punch of half-width b = 1 on a block, plane strain, H = 0,
sigma_y = 1: Prandtl's limit load is (2 + pi) k b for the half model (k = sigma_y /
sqrt 3). Half model 4b x 2b (symmetry plane x = 0, the other sides clamped), which
contains Prandtl's mechanism (it reaches 3b sideways and about 1.4b down) and whose
clamped sides can only add strength, so F_c = (2 + pi) k b. Crossed pattern, n
squares per b, graded (power 2) toward the punch edge, which is a node.

For each mesh: the static program of the equilibrium element (``static_limit_load``)
and the kinematic program with P1 and P2 velocities (``kinematic_limit_load``),
each in its own process, time and peak memory; ratio = F_upper / F_lower. Also: the
same meshes without grading, the P2 bound on the two-triangle (diagonal) pattern,
where P1 locks, and a 3D quarter model of a flat circular punch. Writes ``limit.json`` and
``limit.md`` beside this file (or into ``--out``; ``--quick`` writes into
``benchmarks/bounds/quick/``); ``--report`` renders ``limit.md`` again from ``limit.json``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
PRANDTL = (2 + np.pi) / np.sqrt(3)  # (2 + pi) k b with sigma_y = b = 1
GOAL = 1.02
STUDY = "limit"
TITLE = "Limit-load bracket on Prandtl's punch"

#: (n squares per b, grading, pattern, what)
FULL = ([(n, 2.0, "crossed", w) for n in (2, 4, 8, 16, 32) for w in ("lower", "upper-1", "upper-2")]
        + [(n, 1.0, "crossed", w) for n in (4, 8, 16) for w in ("lower", "upper-1", "upper-2")]
        + [(n, 2.0, "diagonal", w) for n in (4, 8, 16) for w in ("lower", "upper-1", "upper-2")])
QUICK = [(n, 2.0, "crossed", w) for n in (2, 4) for w in ("lower", "upper-1", "upper-2")]
#: 3D: a quarter model of a flat circular punch (radius 1) on a 2 x 2 x 2 block, n elements per unit length
FULL_3D = [(n, w) for n in (2, 3, 4) for w in ("lower", "upper-1", "upper-2")]
QUICK_3D = [(2, w) for w in ("lower", "upper-1", "upper-2")]


def half_punch(n: int, grading: float, pattern: str):
    import elastoplast as ep

    mesh = ep.structured_mesh([4.0, 2.0], [4 * n, 2 * n], contact_radius=1.0, origin=[0.0, 0.0],
                              contact_center=[1.0], grading=grading, pattern=pattern)
    groups = dict(mesh.groups)
    bottom = groups["bottom"]
    groups["contact"] = bottom[np.all(mesh.points[bottom][:, :, 0] <= 1.0 + 1e-12, axis=1)]
    mesh = ep.Mesh(points=mesh.points, cells=mesh.cells, groups=groups)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # perfect plasticity
        return ep.discretize(ep.Problem(mesh=mesh, material=ep.Material(1000.0, 0.3, 1.0, 0.0),
                                        boundary=ep.Boundary(("xmax", "top"), ("contact",), {0: ("xmin",)}),
                                        obstacle=ep.Obstacle("flat", 2, center=(0.0,)), force=1.0))


def quarter_punch(n: int):
    """Quarter model (symmetry planes x = 0, y = 0) of a flat punch of radius 1 on a
    2 x 2 x 2 block clamped on its other sides and top; Γ0 is the union of the bottom
    facets inside the radius (a staircase polygon)."""
    import warnings

    import elastoplast as ep

    mesh = ep.structured_mesh([2.0, 2.0, 2.0], [2 * n] * 3, contact_radius=1.0, origin=[0.0, 0.0, 0.0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # perfect plasticity
        return ep.discretize(ep.Problem(mesh=mesh, material=ep.Material(1000.0, 0.3, 1.0, 0.0),
                                        boundary=ep.Boundary(("xmax", "ymax", "top"), ("contact",),
                                                             {0: ("xmin",), 1: ("ymin",)}),
                                        obstacle=ep.Obstacle("flat", 3, center=(0.0, 0.0)), force=1.0))


def contact_area(disc) -> float:
    cf = np.concatenate([disc.mesh.groups[name] for name in disc.problem.boundary.contact])
    X = disc.mesh.points[cf][:, :, :2]
    u, v = X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]
    return float(0.5 * np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]).sum())


def run_one(n: int, grading: float, pattern: str, what: str) -> dict:
    from elastoplast.bounds.equilibrium.bound import static_limit_load
    from elastoplast.bounds.limit_load import LimitOptions, kinematic_limit_load

    disc = quarter_punch(n) if pattern == "3d" else half_punch(n, grading, pattern)
    out = {"n_elements": int(disc.n_elements)}
    if pattern == "3d":
        out["contact_area"] = contact_area(disc)
    t0 = time.perf_counter()
    if what == "lower":
        r = static_limit_load(disc)
        out.update(F=r.F_lower, certified=bool(r.certified), iterations=r.iterations, message=r.message)
    else:
        r = kinematic_limit_load(disc, LimitOptions(order=int(what[-1])))
        out.update(F=r.F_upper, certified=r.certified, iterations=r.iterations, trace_residual=r.trace_residual,
                   solver_value=r.solver_value, message=r.message)
    out["time_s"] = time.perf_counter() - t0
    out["peak_rss_mb"] = peak_memory() / 2**20
    return out


def spawn(n: int, grading: float, pattern: str, what: str) -> dict:
    """:func:`run_one` in its own process."""
    return run_child(__file__, [n, grading, pattern, what], cwd=ROOT)


def _rows(results: dict):
    meshes: dict = {}
    for r in results["runs"]:
        meshes.setdefault((r["n"], r["grading"], r["pattern"]), {})[r["what"]] = r["result"]
    return meshes


def report(results: dict) -> str:
    lines = ["Half model 4b x 2b, punch half-width b = 1, sigma_y = 1, H = 0; Prandtl: F_c = (2 + pi) k b = "
             f"{PRANDTL:.6f}. Each program in its own process (time: the whole call; memory: peak RSS).",
             "`ratio` = F_upper / F_lower with the better (smaller) upper bound; goal <= 1.02 at the finest mesh.", "",
             "| pattern | grading | n per b | triangles | F_lower / Prandtl | F_upper P1 / Prandtl | F_upper P2 / Prandtl "
             "| ratio | certified | lower s | P1 s | P2 s | lower MB | P2 MB |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for (n, g, pat), r in _rows(results).items():
        if pat == "3d":
            continue
        lo, p1, p2 = r.get("lower", {}), r.get("upper-1", {}), r.get("upper-2", {})
        if any("error" in x for x in (lo, p1, p2)):
            lines.append(f"| {pat} | {g:g} | {n} | error: {lo.get('error', '')} {p1.get('error', '')} {p2.get('error', '')} |")
            continue
        best = min(p1["F"], p2["F"])
        cert = lo["certified"] and (p1["certified"] if p1["F"] <= p2["F"] else p2["certified"])
        lines.append(f"| {pat} | {g:g} | {n} | {lo['n_elements']} | {lo['F'] / PRANDTL:.5f} | {p1['F'] / PRANDTL:.5f} | "
                     f"{p2['F'] / PRANDTL:.5f} | {best / lo['F']:.4f} | {cert} | {lo['time_s']:.2f} | {p1['time_s']:.2f} | "
                     f"{p2['time_s']:.2f} | {lo['peak_rss_mb']:.0f} | {p2['peak_rss_mb']:.0f} |")
    crossed = [(n, r) for (n, g, pat), r in _rows(results).items() if pat == "crossed" and g == 2.0
               and all("F" in r.get(w, {}) for w in ("lower", "upper-1", "upper-2"))]
    if crossed:
        n, r = max(crossed, key=lambda t: t[0])
        ratio = min(r["upper-1"]["F"], r["upper-2"]["F"]) / r["lower"]["F"]
        lines += ["", f"Finest graded crossed mesh (n = {n}): ratio {ratio:.4f}, goal {GOAL}: "
                      f"{'met' if ratio <= GOAL else 'missed'}."]
    rows3 = [(n, r) for (n, g, pat), r in _rows(results).items() if pat == "3d"]
    if rows3:
        lines += ["", "3D: quarter model of a flat circular punch (radius 1, Γ0 the bottom facets inside it) on a "
                  "2 x 2 x 2 block, uniform tetrahedra, n per unit length; forces in units of sigma_y |Γ0| (the "
                  "uniaxial column under Γ0 is admissible, so F_c >= sigma_y |Γ0|). P1 tetrahedra lock.", "",
                  "| n | tetrahedra | F_lower / (sigma_y A) | F_upper P1 / (sigma_y A) | F_upper P2 / (sigma_y A) | ratio "
                  "| certified | lower s | P2 s | lower MB | P2 MB |", "|---|---|---|---|---|---|---|---|---|---|---|"]
        for n, r in rows3:
            lo, p1, p2 = r.get("lower", {}), r.get("upper-1", {}), r.get("upper-2", {})
            if any("error" in x for x in (lo, p1, p2)):
                lines.append(f"| {n} | error: {lo.get('error', '')} {p1.get('error', '')} {p2.get('error', '')} |")
                continue
            A = lo["contact_area"]
            lines.append(f"| {n} | {lo['n_elements']} | {lo['F'] / A:.4f} | {p1['F'] / A:.4f} | {p2['F'] / A:.4f} | "
                         f"{p2['F'] / lo['F']:.4f} | {lo['certified'] and p2['certified']} | {lo['time_s']:.2f} | "
                         f"{p2['time_s']:.2f} | {lo['peak_rss_mb']:.0f} | {p2['peak_rss_mb']:.0f} |")
    lines += ["", "Reading the table: every F_lower lies below Prandtl's load and every F_upper above it, as the two "
              "theorems require (F_c is exactly Prandtl's load for this block). Grading toward the punch edge, where "
              "the velocity field fans out, matters more than the element count: at 8192 triangles the uniform mesh "
              "brackets within 2.2%, the graded one within 0.4%. On the crossed pattern P1 and P2 give about the same "
              "bound for the same time (P2 on a mesh twice as coarse); P2 does not need the crossed pattern (the "
              "diagonal rows: P1 locks there, the bound is infinite), and in 3D P1 locks on practically any mesh, so "
              "P2 is the default (LimitOptions.order). In 3D the bracket stays wide at the sizes these programs reach "
              "on two cores (1.63 at 3072 tetrahedra, with Γ0 a coarse staircase of the disc); the P2 program's time "
              "grows fast (Clarabel's QDLDL factorisation of the KKT system dominates)."]
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path) -> dict:
    quick = mode == "quick"
    results = {"prandtl": PRANDTL, "runs": []}
    runs = (QUICK if quick else FULL) + [(n, 1.0, "3d", w) for n, w in (QUICK_3D if quick else FULL_3D)]
    for n, g, pat, what in runs:
        res = spawn(n, g, pat, what)
        results["runs"].append({"n": n, "grading": g, "pattern": pat, "what": what, "result": res})
        print(json.dumps(results["runs"][-1]), flush=True)
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "crossed graded meshes n = 2, 4 and the 3D quarter at n = 2", HERE, TITLE,
                      "limit-load study", measure, report, argv=argv, study=STUDY,
                      child=lambda spec: run_one(*spec))


if __name__ == "__main__":
    sys.exit(main())
