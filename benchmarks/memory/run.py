"""Memory of building a mesh and its Discretization: measured peak RSS against
``elastoplast.limits.discretization_bytes``, and meshio's peak against
``mesh_read_bytes``.

    python benchmarks/memory/run.py             # full run: results.json, REPORT.md in this folder
    python benchmarks/memory/run.py --quick     # small cases, into quick/ (not committed)
    python benchmarks/memory/run.py --report    # only REPORT.md again, from results.json

Each case runs in a fresh process and reads its own peak RSS (VmHWM,
``harness.peak_memory``); the figure is the peak over the RSS the process had
after importing elastoplast.
"""

from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record  # noqa: E402

HERE = Path(__file__).resolve().parent

BUILD = {"quick": [(2, [200, 100]), (3, [24, 24, 12])],
         "full": [(2, [200, 100]), (2, [400, 200]), (2, [800, 400]), (3, [24, 24, 12]), (3, [40, 40, 20]),
                  (3, [64, 64, 32])]}
READ = {"quick": [(2, [200, 100])], "full": [(2, [400, 200]), (3, [40, 40, 20])]}
FORMATS = [("gmsh22", False, ".msh"), ("gmsh22", True, ".msh"), ("vtu", True, ".vtu"), ("vtu", False, ".vtu"),
           ("vtk", True, ".vtk"), ("vtk", False, ".vtk")]


def problem_dict(dim: int, divisions: list[int]) -> dict:
    if dim == 2:
        mesh = {"generator": "rectangle", "size": [20.0, 10.0], "contact_radius": 2.5}
        obstacle = {"shape": "cylinder", "radius": 40.0}
    else:
        mesh = {"generator": "box", "size": [12.0, 12.0, 6.0], "contact_radius": 2.5}
        obstacle = {"shape": "sphere", "radius": 40.0}
    mesh.update(divisions=divisions, grading=1.5)
    return {"mesh": mesh, "obstacle": obstacle, "load": {"force": 1000.0},
            "material": {"E": 2e5, "nu": 0.3, "yield_stress": 1500.0, "hardening": 1e4}}


def reset_peak() -> int:
    """Reset this process's peak RSS to its current RSS (``echo 5 > /proc/self/clear_refs``)
    and return it in bytes; where the reset is refused, the peak so far."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        pass
    return peak_memory()


def worker_build(dim: int, divisions: list[int]) -> dict:
    import elastoplast as ep
    from elastoplast.limits import discretization_bytes, structured_counts

    before = reset_peak()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        disc = ep.discretize(ep.problem_from_dict(problem_dict(dim, divisions)))
    measured = peak_memory() - before
    estimate = discretization_bytes(dim, *structured_counts(divisions))
    return {"dim": dim, "divisions": divisions, "n_elements": disc.n_elements, "n_nodes": disc.mesh.n_nodes,
            "measured_bytes": measured, "estimate_bytes": estimate, "ratio": measured / estimate}


def worker_read(path: str, traced: bool) -> dict:
    """meshio's peak: the peak RSS increase or, in a separate process, the peak of
    traced allocations (tracemalloc sees every NumPy buffer, also those allocated and
    never touched, which RSS does not; its bookkeeping would inflate RSS, hence two runs)."""
    import tracemalloc

    import meshio

    before = reset_peak()
    if traced:
        tracemalloc.start()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        meshio.read(path)
    measured = tracemalloc.get_traced_memory()[1] if traced else peak_memory() - before
    return {"measured_bytes": measured}


def child(spec: list) -> dict:
    """``["build", dim, divisions]`` or ``["read", path, traced]``, in this process."""
    kind, *rest = spec
    return worker_build(*rest) if kind == "build" else worker_read(*rest)


def measure_read(path: Path) -> dict:
    from elastoplast.limits import mesh_read_bytes

    size = path.stat().st_size
    rss = run_child(__file__, ["read", str(path), False], check=True)["measured_bytes"]
    traced = run_child(__file__, ["read", str(path), True], check=True)["measured_bytes"]
    return {"file": path.name, "size_bytes": size, "rss_bytes": rss, "traced_bytes": traced,
            "rss_per_file_byte": rss / size, "traced_per_file_byte": traced / size,
            "factor": mesh_read_bytes(path, size) // size}


def write_mesh_files(dim: int, divisions: list[int], folder: Path) -> list[Path]:
    import meshio
    import numpy as np

    import elastoplast as ep

    mesh = ep.structured_mesh(*([20.0, 10.0] if dim == 2 else [12.0, 12.0, 6.0],), divisions, 2.5, grading=1.5)
    names = list(mesh.groups)
    facet = "line" if dim == 2 else "triangle"
    cells = [("triangle" if dim == 2 else "tetra", mesh.cells)] + [(facet, mesh.groups[k]) for k in names]
    tags = [np.full(len(mesh.cells), 100)] + [np.full(len(mesh.groups[k]), i + 1) for i, k in enumerate(names)]
    points = mesh.points if dim == 3 else np.column_stack([mesh.points, np.zeros(mesh.n_nodes)])
    field = {k: np.array([i + 1, dim - 1]) for i, k in enumerate(names)}
    paths = []
    for fmt, binary, suffix in FORMATS:
        path = folder / f"{dim}d_{fmt}_{'binary' if binary else 'ascii'}{suffix}"
        data = {"gmsh:physical": tags, "gmsh:geometrical": tags} if fmt == "gmsh22" else {"tag": tags}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            meshio.write(path, meshio.Mesh(points, cells, cell_data=data, field_data=field if fmt == "gmsh22" else None),
                         file_format=fmt, binary=binary)
        paths.append(path)
    return paths


TITLE = "Memory of the input stage: estimates against measured peaks"


def markdown(results: dict) -> str:
    """The report's body: both tables of ``results``."""
    builds, reads = results["build"], results["read"]
    lines = ["## Mesh + discretisation: peak RSS increase against discretization_bytes", "",
             "| dim | divisions | elements | nodes | measured MiB | estimate MiB | measured / estimate |",
             "|---|---|---|---|---|---|---|"]
    lines += [f"| {b['dim']} | {b['divisions']} | {b['n_elements']} | {b['n_nodes']} | {b['measured_bytes'] / 2**20:.1f} "
              f"| {b['estimate_bytes'] / 2**20:.1f} | {b['ratio']:.3f} |" for b in builds]
    lines += ["", "## meshio.read: peak memory per byte of file, against mesh_read_bytes' factor", "",
              "| dim | file | size MiB | peak RSS / size | traced peak / size | factor |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['dim']} | {r['file']} | {r['size_bytes'] / 2**20:.2f} | {r['rss_per_file_byte']:.2f} | "
              f"{r['traced_per_file_byte']:.2f} | {r['factor']} |" for r in reads]
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path) -> dict:
    """Every case of ``mode``, each in its own process."""
    builds = [run_child(__file__, ["build", dim, div], check=True) for dim, div in BUILD[mode]]
    reads = []
    with tempfile.TemporaryDirectory() as tmp:
        for dim, div in READ[mode]:
            for path in write_mesh_files(dim, div, Path(tmp)):
                reads.append({"dim": dim, **measure_read(path)})
    return {"quick": mode == "quick", "build": builds, "read": reads}


def main(argv=None) -> int:
    return run_record(__doc__, "small cases", HERE, TITLE, "memory benchmark", measure, markdown, argv=argv, child=child)


if __name__ == "__main__":
    sys.exit(main())
