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

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record  # noqa: E402

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
            "peak_gb": peak_memory() / 1e9, "signature": sig}


def render(res: dict) -> str:
    runs = res["runs"]
    lines = [f"{runs['file']['n_elements']:,} tetrahedra (the default box, divisions [2n, 2n, n], n = {res['n']}) as a "
             f"gmsh 2.2 binary file, {res['file_mb']:.0f} MB, written in {res['write_s']:.1f} s. Same operators from "
             f"the file as from the generator: **{res['same_operators']}**.", "",
             "| source | mesh s | discretise s | peak GB |", "|---|---|---|---|"]
    for label, r in runs.items():
        lines.append(f"| {label} | {r['mesh_s']:.1f} | {r['discretize_s']:.1f} | {r['peak_gb']:.2f} |")
    return "\n".join(lines) + "\n"


def run_both(mode: str, out: Path) -> dict:
    """Write the file, then :func:`measure` the generator and the file, each in its own process."""
    n = 8 if mode == "quick" else 35
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "box.msh"
        t0 = time.perf_counter()
        write_gmsh(n, path)
        t_write = time.perf_counter() - t0
        runs = {label: run_child(__file__, [n, arg], check=True) for label, arg in (("generator", "-"), ("file", str(path)))}
        size_mb = path.stat().st_size / 1e6
    same = runs["generator"]["signature"] == runs["file"]["signature"]
    return {"n": n, "write_s": t_write, "file_mb": size_mb, "runs": runs, "same_operators": same}


def main(argv=None) -> int:
    return run_record(__doc__, "12k tetrahedra (n = 8)", HERE, TITLE, "mesh-file study", run_both, render, argv=argv,
                      study=STUDY, child=lambda spec: measure(*spec))


if __name__ == "__main__":
    sys.exit(main())
