"""Side study: a mesh file of a million tetrahedra goes through the same path as the box generator.

    python benchmarks/scale/meshfile.py            # 1.03M tetrahedra (n = 35)
    python benchmarks/scale/meshfile.py --quick    # 12k tetrahedra (n = 8), into quick/
    python benchmarks/scale/meshfile.py --report   # meshfile.md again from meshfile.json

Writes the default problem's box mesh (divisions [2n, 2n, n]) as a gmsh 2.2 file
with its facet groups as physical groups, then times, each in its own process,
(a) the box generator + discretisation and (b) reading the file + the same
discretisation, with each process's peak memory, and checks that both give the
same operators (element volumes, free dofs, contact nodes, obstacle gaps).
Writes ``meshfile.json`` and ``meshfile.md`` beside this file (``--out`` to change).
"""

from __future__ import annotations

import argparse
import json
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
STUDY = "meshfile"
TITLE = "A mesh file through the generator's path"


def problem_dict(n: int, mesh_file: Path | None) -> dict:
    from elastoplast.problem.definition import read_toml

    d = read_toml(ROOT / "elastoplast" / "data" / "default.toml")
    d["mesh"]["divisions"] = [2 * n, 2 * n, n]
    if mesh_file is not None:
        d["mesh"] = {"file": str(mesh_file)}
        d["boundary"] = {"clamped": ["xmin", "xmax", "ymin", "ymax", "top"], "contact": ["contact"]}
    return d


def write_gmsh(n: int, path: Path) -> None:
    """The generator's mesh as gmsh 2.2 with named physical groups."""
    import meshio

    from elastoplast.problem.definition import problem_from_dict

    mesh = problem_from_dict(problem_dict(n, None)).mesh
    names = sorted(mesh.groups)
    tags = {name: i + 1 for i, name in enumerate(names)}
    cells = [("tetra", mesh.cells)] + [("triangle", mesh.groups[name]) for name in names]
    phys = [np.full(mesh.n_elements, 100)] + [np.full(len(mesh.groups[name]), tags[name]) for name in names]
    field_data = {name: np.array([tags[name], 2]) for name in names} | {"body": np.array([100, 3])}
    out = meshio.Mesh(mesh.points, cells, cell_data={"gmsh:physical": phys, "gmsh:geometrical": phys},
                      field_data=field_data)
    meshio.write(path, out, file_format="gmsh22", binary=True)


def measure(n: int, mesh_file: str) -> dict:
    import elastoplast as ep
    from elastoplast.problem.definition import problem_from_dict

    t0 = time.perf_counter()
    prob = problem_from_dict(problem_dict(n, Path(mesh_file) if mesh_file != "-" else None))
    t1 = time.perf_counter()
    disc = ep.discretize(prob)
    t2 = time.perf_counter()
    sig = {"volume": float(disc.volumes.sum()), "n_free": int(disc.n_free), "n_contact": int(disc.n_contact),
           "psi_sum": float(disc.psi.sum()), "B_nnz": int(disc.B.nnz), "contact_area": float(disc.contact_area.sum())}
    return {"n_elements": disc.n_elements, "mesh_s": t1 - t0, "discretize_s": t2 - t1,
            "peak_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6, "signature": sig}


def render(res: dict) -> str:
    runs = res["runs"]
    lines = [f"{runs['file']['n_elements']:,} tetrahedra (the default box, divisions [2n, 2n, n], n = {res['n']}) as a "
             f"gmsh 2.2 binary file, {res['file_mb']:.0f} MB, written in {res['write_s']:.1f} s. Same operators from "
             f"the file as from the generator: **{res['same_operators']}**.", "",
             "| source | mesh s | discretise s | peak GB |", "|---|---|---|---|"]
    for label, r in runs.items():
        lines.append(f"| {label} | {r['mesh_s']:.1f} | {r['discretize_s']:.1f} | {r['peak_gb']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    from elastoplast.io.provenance import record_dir, record_parser, rewrite_report, run_child, write_record

    ap = record_parser(__doc__, quick="12k tetrahedra (n = 8)")
    ap.add_argument("--measure", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.measure:
        n, mesh_file = json.loads(args.measure)
        print(json.dumps(measure(int(n), mesh_file)))
        return
    out = record_dir(HERE, args.quick, args.out)
    if args.report:
        rewrite_report(out, TITLE, render, study=STUDY)
        return
    n = 8 if args.quick else 35
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "box.msh"
        t0 = time.perf_counter()
        write_gmsh(n, path)
        t_write = time.perf_counter() - t0
        runs = {}
        for label, arg in (("generator", "-"), ("file", str(path))):
            runs[label] = run_child(__file__, [n, arg], flag="--measure")
            if "error" in runs[label]:
                raise SystemExit(f"{label}: {runs[label]['error']}")
        size_mb = path.stat().st_size / 1e6
    same = runs["generator"]["signature"] == runs["file"]["signature"]
    res = write_record(out, {"n": n, "write_s": t_write, "file_mb": size_mb, "runs": runs, "same_operators": same},
                       TITLE, render, study=STUDY)
    print(render(res))


if __name__ == "__main__":
    main()
