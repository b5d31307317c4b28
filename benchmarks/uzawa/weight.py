"""Iterations of Uzawa against the weight w of V in the metric |eps(v)|^2 + w V^2.

The paper writes w = 1; in 3D the two terms have different units (length^3 and
length^2), so w is a choice. Uzawa only, tol 1e-6, one certificate per
iteration (exact counts). Usage::

    python benchmarks/uzawa/weight.py            # weight.json and weight.md in this folder
    python benchmarks/uzawa/weight.py --quick    # two small cases, into quick/ (not committed)
    python benchmarks/uzawa/weight.py --report   # only weight.md again, from weight.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from common import family
from elastoplast.solvers.uzawa import UzawaOptions, solve_uzawa

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
TITLE = "Uzawa: the weight w of V in the metric |eps(v)|^2 + w V^2"
CASES = [("cylinder_2d", [40, 20]), ("cylinder_2d", [80, 40]), ("sphere_block_3d", [8, 8, 4]),
         ("sphere_block_3d", [16, 16, 8]), ("sphere_quarter_3d", [8, 8, 8])]
QUICK = [("cylinder_2d", [20, 10]), ("sphere_block_3d", [6, 6, 3])]
#: weights in the problem's units (mm^(d-2)); None is the automatic choice
WEIGHTS = [None, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0]
TOL = 1e-6


def markdown(data: dict) -> str:
    """The report's body: iterations per case (rows) and weight (columns)."""
    rows = data["rows"]
    ws = list(dict.fromkeys(r["weight"] for r in rows))
    out = [f"Uzawa iterations to KKT <= {data.get('tol', TOL):g}, w in the problem's units (mm^(d-2)); `auto` is the "
           "default, 1 is the paper's literal metric.", "",
           "| problem | elements | " + " | ".join("auto" if w is None else f"w = {w:g}" for w in ws) + " |",
           "|---|---|" + "---|" * len(ws)]
    for key in dict.fromkeys((r["problem"], tuple(r["divisions"])) for r in rows):
        sel = {r["weight"]: r for r in rows if (r["problem"], tuple(r["divisions"])) == key}
        first = next(iter(sel.values()))
        out.append(f"| {key[0]} | {first['n_elements']} | "
                   + " | ".join(str(sel[w]["iterations"]) + ("" if sel[w]["status"] == "converged" else " (not conv.)")
                                for w in ws) + " |")
    return "\n".join(out) + "\n"


def measure(mode: str, out: Path) -> dict:
    rows = []
    for problem, div in QUICK if mode == "quick" else CASES:
        disc = family(problem, div)
        for w in WEIGHTS:
            sol = solve_uzawa(disc, UzawaOptions(tol=TOL, check_every=1, max_iter=3000, rigid_weight=w))
            rows.append({"problem": problem, "divisions": div, "n_elements": disc.n_elements, "weight": w,
                         "status": sol.status.value, "iterations": sol.iterations, "U": sol.U})
            print(json.dumps(rows[-1]), flush=True)
    return {"quick": mode == "quick", "tol": TOL, "rows": rows}


def main(argv=None) -> int:
    return run_record(__doc__, "two small cases", HERE, TITLE, "weight study", measure, markdown, argv=argv,
                      study="weight")


if __name__ == "__main__":
    sys.exit(main())
