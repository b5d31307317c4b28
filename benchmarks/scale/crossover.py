"""Side study: the 2D crossover of the direct and iterative paths (cylinder_2d, divisions [2m, m]).

    python benchmarks/scale/crossover.py            # m = 80, 160, 320, 640 (25k .. 410k triangles)
    python benchmarks/scale/crossover.py --quick    # m = 40, 80, into quick/
    python benchmarks/scale/crossover.py --report   # crossover.md again from crossover.json

The 3D crossover is read off the main run (run.py); this measures the same
cases on the 2D plane-strain problem, where direct factorisations fill in far
less. Each case runs in its own process (run.py's ``spawn``); answers are
compared with the direct Newton answer. Writes ``crossover.json`` and ``crossover.md``
beside this file (``--out`` to change).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from run import TOL, spawn  # noqa: E402

STUDY = "crossover"
TITLE = f"2D crossover: direct against AMG (cylinder_2d, KKT <= {TOL:g})"
KINDS = ["newton[pardiso]", "newton[amg]", "uzawa[direct]", "uzawa[amg]"]


def render(res: dict) -> str:
    lines = ["| triangles | case | wall s | CPU s | peak GB | iterations | status | dU vs ref | stress err vs ref |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in res["records"]:
        if "error" in r:
            lines.append(f"| | {r['kind']} | error: {r['error']} | | | | | | |")
            continue
        du = f"{r['dU_rel']:.1e}" if "dU_rel" in r else ""
        se = f"{r['stress_error_energy']:.1e}" if "stress_error_energy" in r else ""
        lines.append(f"| {r['n_elements']:,} | {r['kind']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['peak_gb']:.2f} "
                     f"| {r['iterations']} | {r['status']} | {du} | {se} |")
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path) -> dict:
    sizes = [40, 80] if mode == "quick" else [80, 160, 320, 640]
    records = []
    with tempfile.TemporaryDirectory() as store:
        for m in sizes:
            for kind in KINDS:
                rec = spawn(m, kind, 2, Path(store))
                records.append(rec)
                print(f"2D m={m} {kind}: {rec.get('n_elements')} el, {rec.get('wall_s', float('nan')):.1f} s wall, "
                      f"{rec.get('cpu_s', float('nan')):.1f} s CPU, {rec.get('status')} {rec.get('error', '')}",
                      flush=True)
    return {"records": records}


def main(argv=None) -> int:
    return run_record(__doc__, "m = 40, 80", HERE, TITLE, "2D crossover study", measure, render, argv=argv,
                      study=STUDY)


if __name__ == "__main__":
    sys.exit(main())
