"""Iterations of Uzawa against the weight w of V in the metric |eps(v)|^2 + w V^2.

The paper writes w = 1; in 3D the two terms have different units (length^3 and
length^2), so w is a choice. Uzawa only, tol 1e-6, one certificate per
iteration (exact counts). Usage::

    python benchmarks/uzawa/weight.py     # writes weight.json beside this file
"""

from __future__ import annotations

import json
from pathlib import Path

from common import family
from elastoplast.uzawa import UzawaOptions, solve_uzawa

CASES = [("cylinder_2d", [40, 20]), ("cylinder_2d", [80, 40]), ("sphere_block_3d", [8, 8, 4]),
         ("sphere_block_3d", [16, 16, 8]), ("sphere_quarter_3d", [8, 8, 8])]
#: weights in the problem's units (mm^(d-2)); None is the automatic choice
WEIGHTS = [None, 1e-3, 1e-2, 1e-1, 1.0, 10.0, 100.0]


def main() -> None:
    rows = []
    for problem, div in CASES:
        disc = family(problem, div)
        for w in WEIGHTS:
            sol = solve_uzawa(disc, UzawaOptions(tol=1e-6, check_every=1, max_iter=3000, rigid_weight=w))
            rows.append({"problem": problem, "divisions": div, "n_elements": disc.n_elements, "weight": w,
                         "status": sol.status.value, "iterations": sol.iterations, "U": sol.U})
            print(json.dumps(rows[-1]), flush=True)
    Path(__file__).with_name("weight.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
