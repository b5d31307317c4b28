"""Side study: the certified energy bracket -J <= Pi* <= Pi and the U bracket (docs/bounds.md).

    python benchmarks/bounds/upper.py [--quick] [--out DIR] [--report]

1. Energy bracket on the 2D cylinder (problems/cylinder_2d.toml, graded, divisions
   2n x n) and the 3D quarter sphere (problems/sphere_quarter_3d.toml) at a few
   sizes: the discrete value value_D = Pi(u_h, U_h) (not a bound for a curved
   obstacle: u_h penetrates between the nodes), the upper bound of u_h with the
   three corrections of ``upper_bound`` (shift V, lift nodes, best mix), the upper
   bound of the solution of ``conservative_discretization``, the lower bound -J of
   the equilibrium element, the relative gap, the stress error bound and the
   share of the gap the non-penetration correction costs; times of each step.
2. U bracket on the cylinder: delta from ``choose_delta`` (with dU/dF from two
   discrete solves), (U_lower, U_upper), its width against the predicted
   2 sqrt(2 gap U'), the widths with 4 delta and delta / 4, and the discrete U_h of
   every mesh of the sequence (all should lie inside every bracket).

Writes ``upper.json`` and ``upper.md`` beside this file (or into ``--out``;
``--quick`` writes into ``benchmarks/bounds/quick/``); ``--report`` renders
``upper.md`` again from ``upper.json``.
"""

from __future__ import annotations

import copy
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
PROBLEMS = ROOT / "problems"
STUDY = "upper"
TITLE = "Energy and U brackets from the certified upper and lower bounds"

ENERGY = {"cylinder_2d": [(20, 10), (40, 20), (80, 40), (160, 80)], "sphere_quarter_3d": [(3, 3, 3), (4, 4, 3), (5, 5, 4)]}
U_MESHES = [(20, 10), (40, 20), (80, 40)]
QUICK_ENERGY = {"cylinder_2d": [(20, 10), (40, 20)], "sphere_quarter_3d": [(3, 3, 3)]}
QUICK_U = [(20, 10)]


def disc_of(problem: str, divisions):
    import elastoplast as ep

    data = ep.read_toml(PROBLEMS / f"{problem}.toml")
    data["mesh"]["divisions"] = list(divisions)
    return ep.discretize(ep.problem_from_dict(copy.deepcopy(data), base_dir=PROBLEMS))


def timed(fn, *args, **kw):
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    return out, time.perf_counter() - t0


def energy_case(problem: str, divisions) -> dict:
    import elastoplast as ep
    from elastoplast.bounds.bracket import combine
    from elastoplast.bounds.upper import conservative_discretization, upper_bound
    from elastoplast.bounds.equilibrium.bound import solve_lower_bound

    disc = disc_of(problem, divisions)
    sol, t_conic = timed(ep.solve, disc, "conic")
    uppers = {}
    for c in ("shift", "lift", "best"):
        ub, t = timed(upper_bound, disc, sol, c)
        uppers[c] = {"Pi": ub.Pi, "shift": ub.shift, "lift": ub.lift, "certified": ub.certified, "time_s": t}
    cons_sol, t_cons = timed(ep.solve, conservative_discretization(disc), "conic")
    cons = upper_bound(disc, cons_sol, "shift")
    uppers["conservative"] = {"Pi": cons.Pi, "shift": cons.shift, "lift": cons.lift, "certified": cons.certified,
                              "time_s": t_cons}
    lower, t_lower = timed(solve_lower_bound, disc)
    best = min((ub for ub in (upper_bound(disc, sol, "best"), cons)), key=lambda u: u.Pi)
    b = combine(best, lower)
    hi, lo = b.energy_upper, b.energy_lower
    return {
        "problem": problem, "divisions": list(divisions), "n_elements": int(disc.n_elements),
        "value_D": sol.value_D, "U_h": sol.U, "penetration": uppers["shift"]["shift"], "uppers": uppers,
        "lower": lo, "lower_certified": bool(lower.certified), "gap_rel": b.energy_gap_rel,
        "stress_error_bound_rel": b.stress_error_bound_rel, "bounds_certified": b.bounds_certified,
        "correction_share": (hi - sol.value_D) / (hi - lo),
        "local_identity": float((b.element_gap.sum() + b.facet_gap.sum() - (hi - lo)) / abs(hi)),
        "time_s": {"conic": t_conic, "conservative_conic": t_cons, "lower": t_lower,
                   "upper_best": uppers["best"]["time_s"]},
    }


def u_case(divisions, U_ref: dict) -> dict:
    from elastoplast.references.certified import bounds_at, energy_bounds
    from elastoplast.bounds.bracket import choose_delta, u_bracket
    from elastoplast.references.solves import displacement_slope

    disc = disc_of("cylinder_2d", divisions)
    (b, t_b) = timed(energy_bounds, disc)
    slope, t_s = timed(displacement_slope, disc)
    gap = b.energy_upper - b.energy_lower
    delta = choose_delta(disc.force, gap, slope)
    out = {"divisions": list(divisions), "n_elements": int(disc.n_elements), "gap_rel": b.energy_gap_rel,
           "dU_dF": slope, "delta_over_F": delta / disc.force, "predicted_width": 2 * np.sqrt(2 * gap * slope),
           "brackets": {}}
    factors = (1.0, 4.0, 0.25) if divisions == (40, 20) else (1.0,)
    t0 = time.perf_counter()
    for f in factors:
        d = min(f * delta, 0.9 * disc.force)
        lo, hi = u_bracket(disc, d, bounds_at(disc))
        out["brackets"][f"{f:g}"] = {"delta_over_F": d / disc.force, "U_lower": lo, "U_upper": hi, "width": hi - lo,
                                     "contains": {k: bool(lo <= v <= hi) for k, v in U_ref.items()}}
    out["time_s"] = {"bounds_at_F": t_b, "slope": t_s, "brackets": time.perf_counter() - t0}
    return out


def report(results: dict) -> str:
    lines = ["Energies in N mm (2D: per mm). `value_D` is the discrete P1 value (below Pi* is possible: u_h penetrates ",
             "between the nodes); `shift` / `lift` / `best` are upper bounds of u_h with the three corrections, "
             "`conservative` the upper bound of the solution with psi lowered by the facet allowance; `gap` uses the "
             "smaller of best and conservative; `corr share` = (upper - value_D) / gap, the part of the gap the "
             "non-penetration costs; `identity` = (sum of local terms - gap) / |upper|.", "",
             "| problem | elements | value_D | shift | lift | best | conservative | lower -J | gap rel | stress err rel "
             "| corr share | identity | certified | conic s | lower s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["energy"]:
        u = r["uppers"]
        lines.append(f"| {r['problem']} | {r['n_elements']} | {r['value_D']:.6g} | {u['shift']['Pi']:.6g} | "
                     f"{u['lift']['Pi']:.6g} | {u['best']['Pi']:.6g} | {u['conservative']['Pi']:.6g} | {r['lower']:.6g} | "
                     f"{r['gap_rel']:.2e} | {r['stress_error_bound_rel']:.3f} | {r['correction_share']:.2f} | "
                     f"{r['local_identity']:.0e} | {r['bounds_certified']} | {r['time_s']['conic']:.2f} | "
                     f"{r['time_s']['lower']:.2f} |")
    lines += ["", "U bracket on the cylinder (delta from choose_delta; the 40 x 20 mesh also with 4 delta and delta / 4). "
              "`contains` lists the meshes whose discrete U_h lies inside.", "",
              "| divisions | elements | gap rel | dU/dF | delta / F | U_lower | U_upper | width / U_h | predicted width / U_h "
              "| contains | time s |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["u"]:
        U_h = results["U_ref"]["x".join(map(str, r["divisions"]))]
        for f, br in r["brackets"].items():
            inside = ", ".join(k for k, v in br["contains"].items() if v)
            lines.append(f"| {'x'.join(map(str, r['divisions']))} ({f} delta) | {r['n_elements']} | {r['gap_rel']:.2e} | "
                         f"{r['dU_dF']:.3e} | {br['delta_over_F']:.3f} | {br['U_lower']:.5g} | {br['U_upper']:.5g} | "
                         f"{br['width'] / U_h:.3f} | {r['predicted_width'] / U_h:.3f} | {inside} | "
                         f"{sum(r['time_s'].values()):.1f} |")
    lines += ["", "Discrete U_h: " + ", ".join(f"{k}: {v:.6g}" for k, v in results["U_ref"].items())]
    cyl = [r for r in results["energy"] if r["problem"] == "cylinder_2d"]
    if len(cyl) >= 2:
        rates = ", ".join(f"{a['gap_rel'] / b['gap_rel']:.1f}" for a, b in zip(cyl, cyl[1:]))
        lines += ["", "Reading the tables:", "",
                  f"- On the cylinder the relative energy gap falls by {rates} per halving of the mesh size; every "
                  "bracket is certified and its local terms sum to the gap to round-off.",
                  "- The non-penetration correction (upper - value_D) is a quarter to a third of the gap here: u_h "
                  "touches the cylinder at the nodes and dips into it by up to k h^2/8 between them. The mixed "
                  "shift/lift correction (`best`) beats the shift of docs/bounds.md a little; solving once more "
                  "with psi lowered by the facet allowance (`conservative`) beats both. Lifting nodes alone is "
                  "costly: a displaced node strains its elements at second order with the stiffness E.",
                  "- The U bracket is about 2 sqrt(2 gap U') wide, as choose_delta predicts; four times a larger or "
                  "smaller delta widens it about twofold. The discrete U_h of every mesh lies in every bracket.",
                  "- The 3D quarter-sphere meshes affordable for the lower bound are far too coarse for the contact "
                  "zone (radius about 1 mm in a 6 mm block): the gaps exceed 100%. The bounds hold, but they say little "
                  "until the 3D lower-bound program scales."]
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path) -> dict:
    import elastoplast as ep

    quick = mode == "quick"
    results = {"energy": [], "u": []}
    for problem, sizes in (QUICK_ENERGY if quick else ENERGY).items():
        for div in sizes:
            results["energy"].append(energy_case(problem, div))
            print(json.dumps(results["energy"][-1]), flush=True)
    meshes = QUICK_U if quick else U_MESHES
    ref_meshes = meshes + ([(160, 80)] if not quick else [(40, 20)])
    results["U_ref"] = {"x".join(map(str, d)): ep.solve(disc_of("cylinder_2d", d), "conic").U for d in ref_meshes}
    for div in meshes:
        results["u"].append(u_case(div, results["U_ref"]))
        print(json.dumps(results["u"][-1]), flush=True)
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "the cylinder at 400 and 1,600 triangles, the 3D quarter at 3 x 3 x 3", HERE, TITLE,
                      "upper-bound study", measure, report, argv=argv, study=STUDY)


if __name__ == "__main__":
    sys.exit(main())
