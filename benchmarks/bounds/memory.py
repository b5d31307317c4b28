"""Side study: peak memory of the lower-bound programs in a row (the U bracket).

    python benchmarks/bounds/memory.py [--quick] [--out DIR] [--report]

The `bounds` command runs three equilibrium-element programs in one process: the
lower bound at F and the U bracket's two at F - delta and F + delta'
(``elastoplast.bounds.upper.u_bracket_of``); the adaptive loop runs many. This measures,
on the 3D quarter sphere (problems/sphere_quarter_3d.toml, divisions n x n x n, SCS)
and the 2D cylinder (problems/cylinder_2d.toml, Clarabel), the process's peak RSS
after the P1 solve, after the lower bound at F and after the bracket, and the
resident memory between the programs, against ``equilibrium.lower_bound_bytes``
(one program) and ``SEQUENCE_MEMORY_FACTOR`` (several in a row). Each case runs in
its own process. Writes ``memory.json`` and ``memory.md``.
"""

from __future__ import annotations

import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
STUDY = "memory"
TITLE = "Peak memory of the lower-bound programs in a row (side study)"
CASES = {"full": [("sphere_quarter_3d", [16, 16, 16]), ("cylinder_2d", [160, 80])],
         "quick": [("sphere_quarter_3d", [4, 4, 4]), ("cylinder_2d", [20, 10])]}


def _peak_gb() -> float:
    return peak_memory() / 1e9


def _current_gb() -> float:
    return int(Path("/proc/self/statm").read_text().split()[1]) * resource.getpagesize() / 1e9


def measure_case(name: str, divisions: list[int]) -> dict:
    """One case, in this process: P1 solve, lower bound at F, U bracket."""
    import elastoplast as ep
    from elastoplast.references.solves import best_upper_bound
    from elastoplast.bounds.bracket import combine
    from elastoplast.references.certified import u_bracket_of
    from elastoplast.bounds.lower import LowerBoundOptions, lower_bound_bytes, lower_bound_solver
    from elastoplast.bounds.equilibrium.bound import solve_lower_bound

    data = ep.read_toml(ROOT / "problems" / f"{name}.toml")
    data["mesh"]["divisions"] = divisions
    disc = ep.discretize(ep.problem_from_dict(data, base_dir=ROOT / "problems"))
    out = {"problem": name, "divisions": divisions, "elements": disc.n_elements,
           "solver": lower_bound_solver(disc, LowerBoundOptions()),
           "estimate_gb": lower_bound_bytes(disc.dim, disc.n_elements) / 1e9}
    sol = ep.solve(disc, "newton")
    out["after_solve_peak_gb"] = _peak_gb()
    t = time.perf_counter()
    low = solve_lower_bound(disc, LowerBoundOptions())
    out["lower_seconds"] = time.perf_counter() - t
    out["after_lower_peak_gb"] = _peak_gb()
    out["after_lower_current_gb"] = _current_gb()
    b = combine(best_upper_bound(disc, sol, method="newton"), low)
    del low
    t = time.perf_counter()
    U_lo, U_hi, _, certified = u_bracket_of(disc, b, sol.U)
    out["bracket_seconds"] = time.perf_counter() - t
    out["after_bracket_peak_gb"] = _peak_gb()
    out["after_bracket_current_gb"] = _current_gb()
    out.update(U_lower=U_lo, U_upper=U_hi, U_h=sol.U, certified=bool(certified and b.bounds_certified))
    return out


def render(res: dict) -> str:
    rows = ["| problem | elements | solver | estimate of one program GB | peak after P1 solve GB | peak after lower bound GB | "
            "resident after it GB | peak after U bracket GB | resident after it GB | bracket peak / lower peak | "
            "lower s | bracket s | certified |", "|" + "---|" * 13]
    for c in res["cases"]:
        rows.append(f"| {c['problem']} | {c['elements']:,} | {c['solver']} | {c['estimate_gb']:.2f} | "
                    f"{c['after_solve_peak_gb']:.2f} | {c['after_lower_peak_gb']:.2f} | {c['after_lower_current_gb']:.2f} | "
                    f"{c['after_bracket_peak_gb']:.2f} | {c['after_bracket_current_gb']:.2f} | "
                    f"{c['after_bracket_peak_gb'] / c['after_lower_peak_gb']:.2f} | {c['lower_seconds']:.0f} | "
                    f"{c['bracket_seconds']:.0f} | {'yes' if c['certified'] else 'NO'} |")
    return ("Peak RSS of one process (mesh, P1 solve by Newton, the lower bound at F, then the U bracket's two "
            "programs), read after each stage; resident memory after each stage; the package's estimate "
            "(`equilibrium.lower_bound_bytes`) of one program. Times are wall-clock on a shared machine.\n\n"
            + "\n".join(rows) + "\n")


def measure(mode: str, out: Path) -> dict:
    cases = []
    for name, divs in CASES[mode]:
        cases.append(run_child(__file__, [name, divs], check=True))
        print(cases[-1], flush=True)
    return {"cases": cases}


def main(argv=None) -> int:
    return run_record(__doc__, "the 3D quarter at 384 tetrahedra and the 2D cylinder at 400 triangles", HERE, TITLE,
                      "lower-bound memory study", measure, render, argv=argv, study=STUDY,
                      child=lambda spec: measure_case(*spec))


if __name__ == "__main__":
    sys.exit(main())
