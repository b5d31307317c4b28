"""Side study for issue 11, part 1: conforming bisection refinement
(``elastoplast.mesh.refinement``) at a million elements, and element shapes under many
rounds of refinement concentrated at the contact centre.

Sections:

* ``timing``: labelling (``initial_state``) and ``refine`` on 2D and 3D meshes
  of about 1M elements (uniform refinement up to ~1M, local refinement of 10,
  20 and 30 % of a ~1M mesh, a second adaptive call on the result), each case
  in its own process so that its peak memory (VmHWM) is its own;
* ``quality``: 20 rounds marking the elements around the node at the contact
  centre, on the package's structured meshes, the ``crossed`` pattern, the gmsh
  punch mesh and an unstructured gmsh box: elements, deepest generation, the
  shape measure (inradius / longest edge, 1 for the regular simplex) and the
  angles between facets (the angles of triangles, the dihedral angles of
  tetrahedra), against the first 2d generations of uniform bisection.

Usage::

    nice python benchmarks/adapt/refine.py            # writes refine.json, refine.md here
    nice python benchmarks/adapt/refine.py --quick    # small cases into benchmarks/adapt/quick/
    python benchmarks/adapt/refine.py --report        # refine.md again from refine.json
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

TIMING = [
    {"name": "3D box, uniform", "mesh": ["box", [28, 28, 28]], "mark": "all"},
    {"name": "3D box, local 10%", "mesh": ["box", [55, 55, 55]], "mark": 0.10},
    {"name": "3D box, local 20%", "mesh": ["box", [55, 55, 55]], "mark": 0.20},
    {"name": "3D box, local 30%", "mesh": ["box", [55, 55, 55]], "mark": 0.30},
    {"name": "3D box, local 20% then 10% again", "mesh": ["box", [46, 46, 46]], "mark": 0.20, "again": 0.10},
    {"name": "3D gmsh box, uniform, then 20% again", "mesh": ["gmsh_box", 0.055], "mark": "all", "again": 0.20},
    {"name": "2D rectangle, uniform", "mesh": ["rectangle", [500, 250]], "mark": "all"},
    {"name": "2D rectangle, local 20%", "mesh": ["rectangle", [1000, 500]], "mark": 0.20},
]
QUICK_TIMING = [
    {"name": "3D box, uniform", "mesh": ["box", [8, 8, 8]], "mark": "all"},
    {"name": "3D box, local 20% then 10% again", "mesh": ["box", [10, 10, 10]], "mark": 0.20, "again": 0.10},
    {"name": "3D gmsh box, uniform, then 20% again", "mesh": ["gmsh_box", 0.5], "mark": "all", "again": 0.20},
    {"name": "2D rectangle, local 20%", "mesh": ["rectangle", [40, 20]], "mark": 0.20},
]
QUALITY = ["rectangle", "crossed", "punch_gmsh", "box", "quarter", "gmsh_box"]
ROUNDS = 20
STUDY = "refine"
TITLE = "Conforming bisection refinement at a million elements (issue 11, part 1)"


# ----------------------------------------------------------------------------
# meshes
# ----------------------------------------------------------------------------


def gmsh_box(h: float, path: Path):
    """Unstructured tetrahedra in [-6, 6]^2 x [0, 6] (the default 3D block) with a
    disc of radius 2.5 in the bottom face as the contact group (gmsh, OCC)."""
    import gmsh

    import elastoplast as ep

    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("box")
        occ = gmsh.model.occ
        box = occ.addBox(-6, -6, 0, 12, 12, 6)
        occ.fragment([(3, box)], [(2, occ.addDisk(0, 0, 0, 2.5, 2.5))])
        occ.synchronize()
        groups: dict[str, list[int]] = {"contact": [], "free_bottom": [], "sides": [], "top": []}
        for _, tag in gmsh.model.getEntities(2):
            x0, y0, z0, x1, y1, z1 = gmsh.model.getBoundingBox(2, tag)
            if abs(z0) < 1e-6 and abs(z1) < 1e-6:
                groups["contact" if x1 - x0 < 6 else "free_bottom"].append(tag)
            elif abs(z0 - 6) < 1e-6 and abs(z1 - 6) < 1e-6:
                groups["top"].append(tag)
            else:
                groups["sides"].append(tag)
        for name, tags in groups.items():
            gmsh.model.setPhysicalName(2, gmsh.model.addPhysicalGroup(2, tags), name)
        gmsh.model.addPhysicalGroup(3, [t for _, t in gmsh.model.getEntities(3)])
        gmsh.option.setNumber("Mesh.MeshSizeMax", 6 * h)
        gmsh.option.setNumber("General.NumThreads", 1)
        gmsh.model.mesh.generate(3)
        gmsh.write(str(path))
    finally:
        gmsh.finalize()
    return ep.read_mesh(path)


def make_mesh(kind: str, arg, tmp: Path):
    import elastoplast as ep

    if kind == "box":
        return ep.structured_mesh([12.0, 12.0, 6.0], arg, 2.5, grading=1.6)
    if kind == "rectangle":
        return ep.structured_mesh([20.0, 10.0], arg, 3.0, grading=1.5)
    if kind == "crossed":
        return ep.structured_mesh([20.0, 10.0], arg, 3.0, grading=1.5, pattern="crossed")
    if kind == "quarter":
        return ep.structured_mesh([6.0, 6.0, 6.0], arg, 2.5, origin=[0.0, 0.0, 0.0], grading=1.6)
    if kind == "punch_gmsh":
        return ep.read_mesh(ROOT / "problems" / "punch_2d.msh")
    if kind == "gmsh_box":
        return gmsh_box(float(arg), tmp / f"gmsh_box_{arg}.msh")
    raise ValueError(kind)


def ball(mesh, share: float) -> np.ndarray:
    """The ``share`` of elements whose centroids are nearest the contact centre."""
    r = np.linalg.norm(mesh.points[mesh.cells].mean(axis=1), axis=1)
    k = max(1, int(round(share * mesh.n_elements)))
    marked = np.zeros(mesh.n_elements, dtype=bool)
    marked[np.argpartition(r, k - 1)[:k]] = True
    return marked


# ----------------------------------------------------------------------------
# timing, one case per process
# ----------------------------------------------------------------------------


def child(spec: dict) -> dict:
    from elastoplast.mesh.refinement import initial_state, refine

    kind, arg = spec["mesh"]
    mesh = make_mesh(kind, arg, Path(spec["tmp"]))
    marked = np.ones(mesh.n_elements, dtype=bool) if spec["mark"] == "all" else ball(mesh, spec["mark"])
    before = peak_memory() / 2**20
    t0 = time.perf_counter()
    state = initial_state(mesh)
    t_label = time.perf_counter() - t0
    t0 = time.perf_counter()
    new, state, parent = refine(mesh, marked, state)
    t_refine = time.perf_counter() - t0
    row = {"n_in": mesh.n_elements, "nodes_in": mesh.n_nodes, "marked": int(marked.sum()),
           "n_out": new.n_elements, "nodes_out": new.n_nodes, "closure_extra": int(new.n_elements - mesh.n_elements - (2**mesh.dim - 1) * marked.sum()),
           "max_generation": int(state.generation.max()), "label_s": t_label, "refine_s": t_refine,
           "rss_before_mb": before}
    if "again" in spec:
        marked2 = ball(new, spec["again"])
        t0 = time.perf_counter()
        newer, state, _ = refine(new, marked2, state)
        row.update({"marked_again": int(marked2.sum()), "n_again": newer.n_elements,
                    "closure_extra_again": int(newer.n_elements - new.n_elements - (2**mesh.dim - 1) * marked2.sum()),
                    "refine_again_s": time.perf_counter() - t0, "max_generation": int(state.generation.max())})
    row["peak_rss_mb"] = peak_memory() / 2**20
    return row


def run_timing(cases: list[dict], tmp: Path) -> list[dict]:
    rows = []
    for spec in cases:
        spec = {**spec, "tmp": str(tmp)}
        row = {**spec, **run_child(__file__, spec)}
        if "error" not in row:
            print(f"  {spec['name']}: {row['n_in']} -> {row['n_out']} elements, label {row['label_s']:.2f} s, "
                  f"refine {row['refine_s']:.2f} s, peak {row['peak_rss_mb']:.0f} MB", flush=True)
        row.pop("tmp")
        rows.append(row)
    return rows


# ----------------------------------------------------------------------------
# quality
# ----------------------------------------------------------------------------


def facet_angles(mesh) -> np.ndarray:
    """Angles between the facets of each simplex, degrees ``(n_el, d(d+1)/2)``:
    with ``g_i`` the gradient of the barycentric coordinate of vertex ``i`` (an
    inward normal of the facet opposite it), the angle between facets ``i, j``
    is ``arccos(-g_i.g_j / |g_i||g_j|)``: the triangle's angles in 2D, the
    dihedral angles in 3D."""
    X = mesh.points[mesh.cells]
    J = np.swapaxes(X[:, 1:] - X[:, :1], 1, 2)
    Jinv = np.linalg.inv(J)
    g = np.concatenate([-Jinv.sum(axis=1, keepdims=True), Jinv], axis=1)
    g /= np.linalg.norm(g, axis=2, keepdims=True)
    d = mesh.dim
    cos = [-np.einsum("ij,ij->i", g[:, i], g[:, j]) for i in range(d + 1) for j in range(i + 1, d + 1)]
    return np.degrees(np.arccos(np.clip(np.stack(cos, axis=1), -1.0, 1.0)))


def shape_row(mesh, generation: np.ndarray | None = None) -> dict:
    """Extremes of the shape measures over all elements and, given the
    generations, over the refined ones (generation >= 1)."""
    from elastoplast.mesh.refinement import shape_quality

    q, a = shape_quality(mesh), facet_angles(mesh)
    row = {"n_el": mesh.n_elements, "q_min": float(q.min()), "q_max": float(q.max()),
           "angle_min": float(a.min()), "angle_max": float(a.max())}
    if generation is not None:
        new = generation >= 1
        row.update({"refined": int(new.sum()), "q_min_refined": float(q[new].min()),
                    "angle_min_refined": float(a[new].min()), "angle_max_refined": float(a[new].max())})
    return row


def run_quality(kinds: list[str], rounds: int, tmp: Path, quick: bool) -> list[dict]:
    from elastoplast.mesh.refinement import refine

    args = {"rectangle": [40, 20], "crossed": [20, 10], "punch_gmsh": None, "box": [8, 8, 4],
            "quarter": [6, 6, 6], "gmsh_box": 0.5 if quick else 0.25}
    out = []
    for kind in kinds:
        mesh = make_mesh(kind, args[kind], tmp)
        d = mesh.dim
        # the first 2d generations of the bisection forest (every element bisected once per step)
        forest, layer, s = [shape_row(mesh)], mesh, None
        for _ in range(2 * d):
            layer, s, _ = refine(layer, np.ones(layer.n_elements, dtype=bool), s, bisections=1)
            forest.append(shape_row(layer, s.generation))
        centre = int(np.argmin(np.linalg.norm(mesh.points, axis=1)))
        history, current, state = [], mesh, None
        t0 = time.perf_counter()
        for k in range(rounds):
            current, state, _ = refine(current, np.any(current.cells == centre, axis=1), state)
            history.append({"round": k + 1, "max_generation": int(state.generation.max()), **shape_row(current, state.generation)})
        elapsed = time.perf_counter() - t0
        row = {"mesh": kind, "dim": d, "initial": forest[0], "forest": forest, "rounds": history, "time_s": elapsed}
        print(f"  {kind}: {mesh.n_elements} -> {current.n_elements} elements in {rounds} rounds, q_min "
              f"{forest[0]['q_min']:.3f}, refined {history[-1]['q_min_refined']:.3f} (forest {min(f['q_min'] for f in forest):.3f})",
              flush=True)
        out.append(row)
    return out


# ----------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------


def report(results: dict) -> str:
    lines = ["Each timing case runs in its own process (`peak` is its VmHWM: mesh generation, labelling and",
             "refinement; `before` is the VmHWM after building the input mesh). `closure` counts the elements",
             "the closure added beyond the 2^d - 1 new ones per marked element. Timings move by up to 2x",
             "between runs on this shared machine.", "",
             "## 1. Time and memory", "",
             "| case | elements in | marked | elements out | nodes out | closure | labelling s | refine s | before MB | peak MB |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["timing"]:
        if "error" in r:
            lines.append(f"| {r['name']} | failed: {r['error']} |||||||||")
            continue
        out = f"{r['n_out']}" + (f" -> {r['n_again']} (2nd call: {r['marked_again']} marked, closure {r['closure_extra_again']}, "
                                 f"{r['refine_again_s']:.2f} s)" if "n_again" in r else "")
        lines.append(f"| {r['name']} | {r['n_in']} | {r['marked']} | {out} | {r['nodes_out']} | {r['closure_extra']} | "
                     f"{r['label_s']:.2f} | {r['refine_s']:.2f} | {r['rss_before_mb']:.0f} | {r['peak_rss_mb']:.0f} |")
    lines += ["", f"## 2. Shapes under {results['rounds']} rounds at the contact centre", "",
              "Each round marks the elements around the input node nearest the contact centre (d bisections each,",
              "plus the closure). `q`: inradius / longest edge over its value for the regular simplex (1: regular,",
              "0: flat). `angles`: the angles of the triangles (2D) or the dihedral angles (3D), degrees.",
              "`initial`: the input mesh; `forest`: the worst over the first 2d generations of uniform bisection of",
              "the same mesh; `refined`: the elements of generation >= 1 after the last round (all the deeper",
              "generations are there).", "",
              "| mesh | elements | max generation | q min initial | q min forest | q min refined | q min all | "
              "angle min initial | angle min refined | angle max refined | time s |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results["quality"]:
        last, f0 = r["rounds"][-1], r["initial"]
        fq = min(f["q_min"] for f in r["forest"])
        lines.append(f"| {r['mesh']} | {f0['n_el']} -> {last['n_el']} | {last['max_generation']} | {f0['q_min']:.4f} | {fq:.4f} | "
                     f"{last['q_min_refined']:.4f} | {last['q_min']:.4f} | {f0['angle_min']:.2f} | {last['angle_min_refined']:.2f} | "
                     f"{last['angle_max_refined']:.2f} | {r['time_s']:.2f} |")
    lines += ["", "Worst shape among the refined elements after each round (q min, generation >= 1). Theory: finitely",
              "many similarity classes per input element (newest-vertex bisection in 2D: at most 4; Maubach's",
              "cycle of d bisections on the Kuhn simplices of the box meshes), so the column must stop moving once",
              "the first generations near the centre have appeared.", "",
              "| mesh | " + " | ".join(str(k) for k in range(1, results["rounds"] + 1)) + " |",
              "|---|" + "---|" * results["rounds"]]
    for r in results["quality"]:
        lines.append(f"| {r['mesh']} | " + " | ".join(f"{h['q_min_refined']:.3f}" for h in r["rounds"]) + " |")
    return "\n".join(lines) + "\n"


def measure(mode: str, out: Path) -> dict:
    """Both sections, the timing cases each in its own process."""
    with tempfile.TemporaryDirectory() as tmp:
        print("timing:", flush=True)
        timing = run_timing(QUICK_TIMING if mode == "quick" else TIMING, Path(tmp))
        print("quality:", flush=True)
        rounds = 6 if mode == "quick" else ROUNDS
        quality = run_quality(QUALITY, rounds, Path(tmp), mode == "quick")
    return {"rounds": rounds, "timing": timing, "quality": quality}


def main(argv=None) -> int:
    return run_record(__doc__, "meshes of a few thousand elements, 6 rounds", HERE, TITLE, "refinement study",
                      measure, report, argv=argv, study=STUDY, child=child)


if __name__ == "__main__":
    sys.exit(main())
