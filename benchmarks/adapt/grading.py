"""Side study: uniform refinement without the problem files' grading (issue 11).

    python benchmarks/adapt/grading.py [--quick] [--out DIR] [--report]

The meshes of ``problems/cylinder_2d.toml`` (grading 2.0) and
``problems/sphere_quarter_3d.toml`` (grading 1.6) are already graded towards the
contact zone, and uniform refinement keeps that grading: the comparison of
``run.py`` is against meshes that are adapted a priori. Here the same starting
divisions with ``grading = 1`` (equal cells), refined uniformly (``uniform``) up to
the same sizes as in ``run.py`` (2D 25,600 triangles, 3D 24,576 tetrahedra), and
the element ratio at equal gap against the adaptive sequences (θ = 0.5) recorded
in ``results.json`` (so run ``run.py`` first).

Writes ``grading.json`` and ``grading.md`` beside this file (``--quick``: into quick/).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import elastoplast as ep
from elastoplast.adapt.records import AdaptOptions, Step, elements_at_gap, fitted_rate
from elastoplast.adapt.loop import uniform
from elastoplast.problem.definition import read_toml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TITLE = "Uniform refinement without grading (side study)"
CASES = {"full": {"2d": ("cylinder_2d", [20, 10], 25_600), "3d": ("sphere_quarter_3d", [4, 4, 4], 24_576)},
         "quick": {"2d": ("cylinder_2d", [10, 5], 1_600), "3d": ("sphere_quarter_3d", [4, 4, 4], 384)}}


def measure(mode: str, record: dict) -> dict:
    out = {"mode": mode, "source": "results.json" if mode == "full" else "quick/results.json", "cases": {}}
    for key, (name, divisions, largest) in CASES[mode].items():
        data = read_toml(ROOT / "problems" / f"{name}.toml")
        data["mesh"]["divisions"] = divisions
        graded = data["mesh"].get("grading", 1.0)
        data["mesh"]["grading"] = 1.0
        t0 = time.perf_counter()
        run = uniform(ep.problem_from_dict(data), AdaptOptions(), max_elements=largest,
                      report=lambda s: print(f"{key} {s.line()}", flush=True))
        out["cases"][key] = {"problem": name, "divisions": divisions, "grading_of_the_file": graded,
                             "seconds": time.perf_counter() - t0, "steps": [s.as_dict() for s in run.steps],
                             "adaptive": record["cases"][key]["runs"]["adaptive 0.5"]["steps"],
                             "graded_uniform": record["cases"][key]["runs"]["uniform"]["steps"]}
    return out


def report(res: dict) -> str:
    body = [f"Adaptive sequences (θ = 0.5) and uniform refinement of the graded meshes from `{res['source']}`; "
            "uniform refinement of the ungraded meshes measured here. `ratio`: the uniform mesh's elements over "
            "the adaptive sequence's at the same gap (log-log interpolation).", "",
            "| case | uniform of | elements | relative gap | fitted p | adaptive elements at that gap | ratio |",
            "|---|---|---|---|---|---|---|"]
    for key, c in res["cases"].items():
        adaptive = [Step(**s) for s in c["adaptive"]]
        for label, steps in ((f"grading {c['grading_of_the_file']:g} (the file's)", c["graded_uniform"]),
                             ("grading 1", c["steps"])):
            st = [Step(**s) for s in steps]
            for s in st:
                n_a = elements_at_gap(adaptive, s.gap_rel)
                reached = n_a == n_a  # NaN: below the adaptive sequence's last gap
                body.append(f"| {key} {c['problem']} | {label} | {s.n_elements:,} | {s.gap_rel:.3e} | "
                            f"{fitted_rate(st):.2f} | {f'{n_a:,.0f}' if reached else '-'} | "
                            f"{f'{s.n_elements / n_a:.1f}' if reached else '-'} |")
    return "\n".join(body)


def main(argv=None) -> int:
    # the adaptive sequences to compare with are those recorded by run.py in the same folder
    return run_record(__doc__, "coarse meshes", HERE, TITLE, "grading study",
                      lambda mode, out: measure(mode, json.loads((out / "results.json").read_text())), report,
                      argv=argv, study="grading")


if __name__ == "__main__":
    sys.exit(main())
