"""Certified bounds on refinement sequences (issue 10): the gap against elements, the
cross-mesh checks, and the cost of the lower bound against the (S) conic solve.

    python benchmarks/bounds/run.py            # full run, about 20-25 minutes on two cores
    python benchmarks/bounds/run.py --quick    # small meshes, about a minute, into quick/
    python benchmarks/bounds/run.py --report   # REPORT.md and the plots again from results.json

Families (each a sequence of meshes of one problem):

* ``cylinder_2d``: problems/cylinder_2d.toml (graded) at divisions 10 x 5, 20 x 10, ...;
* ``sphere_quarter_3d``: problems/sphere_quarter_3d.toml (graded, two symmetry planes);
* ``punch_2d_gmsh``: problems/punch_2d_gmsh.toml on unstructured meshes written by
  problems/make_punch_mesh.py with its element sizes times a factor (needs gmsh, the
  ``mesh`` extra; skipped without it).

Per mesh, two processes (so that each peak memory is its own, VmHWM):

* ``bounds``: the (S) conic solve, timed and its peak memory read at once, then
  :func:`elastoplast.bounds.upper.certified_bounds` with that solution: the energy bracket,
  the stress error bound and (up to :data:`BRACKET_MAX_ELEMENTS`) the U bracket;
* ``lower``: :func:`elastoplast.bounds.lower.solve_lower_bound` alone, timed, with its
  peak memory.

Across the meshes of a family: every lower bound against every upper bound, each U
bracket against the discrete U_h of the same and every finer mesh, the exponent p of
``gap_rel ~ elements^-p`` (least squares in log-log, and per step), and the time
ratio lower / conic. Writes ``results.json`` + ``REPORT.md`` (stamped) and
``gap.png``, ``u_bracket.png``, ``time.png`` (time and peak memory).
"""

from __future__ import annotations

import copy
import json
import math
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
PROBLEMS = ROOT / "problems"
TITLE = "Certified bounds on refinement sequences (issue 10)"

FAMILIES = {
    "cylinder_2d": {"problem": "cylinder_2d.toml", "mesh": "divisions",
                    "label": "2D cylinder, graded structured meshes (problems/cylinder_2d.toml)"},
    "sphere_quarter_3d": {"problem": "sphere_quarter_3d.toml", "mesh": "divisions",
                          "label": "3D quarter sphere, graded structured meshes, two symmetry planes "
                                   "(problems/sphere_quarter_3d.toml)"},
    "sphere_quarter_3d_nested": {"problem": "sphere_quarter_3d.toml", "mesh": "refined", "base": [3, 3, 3],
                                 "nested": True, "same_gamma0": True,
                                 "label": "3D quarter sphere, 3 x 3 x 3 refined by bisection k times next to Γ0 "
                                          "(nested meshes, the same Γ0)"},
    "punch_2d_gmsh": {"problem": "punch_2d_gmsh.toml", "mesh": "gmsh", "same_gamma0": True,
                      "label": "2D paraboloid on unstructured gmsh meshes (problems/punch_2d_gmsh.toml, "
                               "problems/make_punch_mesh.py, sizes times a factor)"},
}

#: divisions (structured), refinements of the base mesh (refined) or the factor on
#: make_punch_mesh.py's element sizes (gmsh)
SIZES = {
    "full": {
        "cylinder_2d": [[10, 5], [20, 10], [40, 20], [80, 40], [160, 80]],
        "sphere_quarter_3d": [[3, 3, 3], [4, 4, 4], [6, 6, 6], [8, 8, 8]],
        "sphere_quarter_3d_nested": [0, 1, 2],
        "punch_2d_gmsh": [2.0, 1.4, 1.0, 0.7, 0.5],
    },
    "quick": {
        "cylinder_2d": [[10, 5], [20, 10], [40, 20]],
        "sphere_quarter_3d": [[3, 3, 3], [4, 4, 3]],
        "punch_2d_gmsh": [2.0, 1.0],
    },
}

#: the U bracket costs two more lower-bound programs: only up to this many elements
#: (about 1.5 minutes per program at 25,600 triangles and 2 minutes at 3,072 tetrahedra
#: on two cores), which keeps the full run near 20 minutes
BRACKET_MAX_ELEMENTS = {2: 10_000, 3: 2_000}

PUNCH_H = (1.0, 0.15)  # make_punch_mesh.py's default h_far, h_contact


# ----------------------------------------------------------------------------
# one mesh, in a child process
# ----------------------------------------------------------------------------


def build(family: str, size, mesh_file: str | None = None):
    """The discretisation of one mesh of ``family``."""
    import elastoplast as ep

    spec = FAMILIES[family]
    data = copy.deepcopy(ep.read_toml(PROBLEMS / spec["problem"]))
    if spec["mesh"] == "gmsh":
        data["mesh"] = {"file": str(mesh_file)}
    else:
        data["mesh"]["divisions"] = list(spec.get("base", size))
    problem = ep.problem_from_dict(data, base_dir=PROBLEMS)
    if spec["mesh"] == "refined":
        problem = replace(problem, mesh=refined_next_to_contact(problem, int(size)))
    return ep.discretize(problem)


def refined_next_to_contact(problem, times: int):
    """``problem``'s mesh after ``times`` conforming bisection refinements
    (:func:`elastoplast.refine`) of the elements with a node on Γ0: each mesh is
    nested in the next, and the facet groups (Γ0, the symmetry planes, the clamped
    sides) are refined with it, so every mesh defines the same continuum problem."""
    import elastoplast as ep

    mesh, state = problem.mesh, None
    for _ in range(times):
        near = np.isin(mesh.cells, mesh.group_nodes(list(problem.boundary.contact))).any(axis=1)
        mesh, state, _ = ep.refine(mesh, near, state)
    return mesh


def write_punch_mesh(factor: float, folder: Path) -> Path:
    """problems/make_punch_mesh.py's mesh with both element sizes times ``factor``."""
    sys.path.insert(0, str(PROBLEMS))
    import make_punch_mesh

    path = folder / f"punch_{factor:g}.msh"
    make_punch_mesh.main(path, h_far=PUNCH_H[0] * factor, h_contact=PUNCH_H[1] * factor)
    return path


def contact_extent(disc, sol=None) -> dict:
    """Γ0 as the mesh defines it: its measure, ``rim``: the distance from the
    obstacle's centre to the nearest point of its rim (its boundary within the
    bottom plane, leaving out parts on symmetry planes), and with a solution
    ``active``: the largest distance of an active contact node from the centre.
    The continuum problem of a mesh is that of its Γ0; the problems of two meshes
    have the same solution when its contact set lies inside both Γ0."""
    from elastoplast.bounds.upper import contact_facets
    from elastoplast.mesh.topology import facet_measure

    mesh, d = disc.mesh, disc.dim
    facets = contact_facets(disc)
    centre = np.asarray(disc.problem.obstacle.center, dtype=float)
    # the (d-2)-faces of the facets (nodes in 2D, edges in 3D); the rim is made of those used once
    faces = np.sort(np.concatenate([np.delete(facets, i, axis=1) for i in range(d)]), axis=1)
    uniq, count = np.unique(faces, axis=0, return_counts=True)
    rim = uniq[count == 1]
    for names in disc.problem.boundary.fix_component.values():
        on_plane = np.zeros(mesh.n_nodes, dtype=bool)
        for name in names:
            on_plane[mesh.group_nodes([name])] = True
        rim = rim[~on_plane[rim].all(axis=1)]
    X = mesh.points[rim][:, :, :-1] - centre
    if d == 2:
        dist = np.abs(X[:, 0, 0])
    else:  # distance to a segment
        a, b = X[:, 0], X[:, 1]
        t = np.clip(np.einsum("ij,ij->i", -a, b - a) / np.maximum(np.einsum("ij,ij->i", b - a, b - a), 1e-300), 0, 1)
        dist = np.linalg.norm(a + t[:, None] * (b - a), axis=1)
    out = {"gamma0_measure": float(facet_measure(mesh.points[facets]).sum()),
           "gamma0_rim": float(dist.min(initial=np.inf))}
    if sol is not None:
        xp = mesh.points[disc.contact_nodes[np.asarray(sol.active, dtype=bool)], :-1] - centre
        out["active_radius"] = float(np.linalg.norm(xp, axis=1).max(initial=0.0))
    return out


def run_bounds(family: str, size, mesh_file: str | None) -> dict:
    """The conic solve (timed, its own peak memory) and the certified bounds."""
    import elastoplast as ep
    from elastoplast.references.certified import certified_bounds

    disc = build(family, size, mesh_file)
    base = peak_memory() / 2**20
    t0 = time.perf_counter()
    sol = ep.solve(disc, "conic")
    conic_s = time.perf_counter() - t0
    conic_mb = peak_memory() / 2**20
    bracket = disc.n_elements <= BRACKET_MAX_ELEMENTS[disc.dim]
    t0 = time.perf_counter()
    rep = certified_bounds(disc, sol, bracket=bracket)
    return {
        "elements": int(disc.n_elements), "nodes": int(disc.mesh.n_nodes), "dim": int(disc.dim),
        "U_h": float(sol.U), "value_D": float(sol.value_D), "status": sol.status.value, "kkt_worst": float(sol.kkt.worst),
        "conic_s": conic_s, "conic_peak_mb": conic_mb, "start_mb": base,
        "bounds_s": time.perf_counter() - t0, "bounds_peak_mb": peak_memory() / 2**20, "bracket": bracket,
        **contact_extent(disc, sol), **rep.as_dict(),
    }


def run_lower(family: str, size, mesh_file: str | None) -> dict:
    """The lower-bound program alone (timed, its own peak memory)."""
    from elastoplast.bounds.equilibrium.bound import solve_lower_bound

    disc = build(family, size, mesh_file)
    base = peak_memory() / 2**20
    t0 = time.perf_counter()
    lb = solve_lower_bound(disc)
    return {"lower_s": time.perf_counter() - t0, "lower_peak_mb": peak_memory() / 2**20, "start_mb": base,
            "energy_lower": -lb.J, "certified": lb.certified, "iterations": lb.iterations,
            "phases_s": lb.timings, "message": lb.message}


def child(spec: list) -> dict:
    """``[what, family, size, mesh_file]`` in this process: :func:`run_bounds` (what
    'bounds') or :func:`run_lower` ('lower')."""
    what, family, size, mesh_file = spec
    return (run_bounds if what == "bounds" else run_lower)(family, size, mesh_file)


def spawn(what: str, family: str, size, mesh_file: str | None) -> dict:
    """Run ``what`` ('bounds' or 'lower') in a fresh process."""
    return run_child(__file__, [what, family, size, mesh_file], cwd=ROOT)


# ----------------------------------------------------------------------------
# across the meshes of a family
# ----------------------------------------------------------------------------


def pair_check(rows: list[dict]) -> dict:
    """Weak duality across meshes: ``lower_i <= upper_j`` for every pair (i, j);
    ``min_margin_rel`` = min over pairs of ``(upper_j - lower_i) / |upper_j|``."""
    lo = np.array([r["energy_lower"] for r in rows])
    hi = np.array([r["energy_upper"] for r in rows])
    margin = (hi[None, :] - lo[:, None]) / np.abs(hi[None, :])
    bad = np.argwhere(margin < 0)
    return {"pairs": int(margin.size), "violations": bad.tolist(), "max_lower": float(lo.max()),
            "min_upper": float(hi.min()), "min_margin_rel": float(margin.min())}


def u_check(rows: list[dict]) -> dict:
    """Each U bracket against U_h of the same and every finer mesh (more elements)."""
    out, checked, inside = [], 0, 0
    for i, r in enumerate(rows):
        if not r.get("bracket") or r.get("U_lower") is None:
            continue
        finer = [j for j, s in enumerate(rows) if s["elements"] >= r["elements"]]
        ok = [bool(r["U_lower"] <= rows[j]["U_h"] <= r["U_upper"]) for j in finer]
        out.append({"mesh": i, "elements": r["elements"], "finer": finer, "inside": ok})
        checked += len(ok)
        inside += sum(ok)
    return {"brackets": out, "checked": checked, "inside": inside}


def rates(rows: list[dict]) -> dict:
    """``gap_rel ~ elements^-p``: p by least squares over all meshes and over the last
    three (:func:`elastoplast.adapt.loop.fitted_rate`), and per step; ``p_h = d p`` is the
    exponent in the mesh size h ~ elements^(-1/d); ``factor`` the gap's drop per step and
    ``per_halving`` the drop per halving of h that each step's exponent implies."""
    from elastoplast.adapt.records import fitted_rate

    steps = [SimpleNamespace(n_elements=r["elements"], gap_rel=r["energy_gap_rel"]) for r in rows]
    n = np.array([r["elements"] for r in rows], dtype=float)
    g = np.array([r["energy_gap_rel"] for r in rows], dtype=float)
    d = rows[0]["dim"]
    per_step = -np.log(g[1:] / g[:-1]) / np.log(n[1:] / n[:-1])
    p_all, p_last = fitted_rate(steps), fitted_rate(steps[-3:])
    return {"p_all": p_all, "p_last3": p_last, "p_h_all": d * p_all, "p_h_last3": d * p_last,
            "per_step": per_step.tolist(), "per_halving": (2.0 ** (d * per_step)).tolist(),
            "factor": (g[:-1] / g[1:]).tolist()}


def family_checks(rows: list[dict]) -> dict:
    """Everything measured across the meshes of a family. ``time_exponent``: q of
    ``seconds ~ elements^q`` over the last three meshes. ``contact_inside_every_gamma0``:
    the largest active contact radius of any U_h lies below the smallest rim of any Γ0
    (then the meshes' continuum problems plausibly share their solution, although
    their Γ0 differ)."""
    ok = [r for r in rows if "error" not in r]
    if len(ok) < 2:
        return {}
    last = ok[-3:]
    n = np.log([r["elements"] for r in last])
    return {"pairs": pair_check(ok), "U": u_check(ok), "rates": rates(ok),
            "time_ratio": [r["lower_s"] / r["conic_s"] for r in ok],
            "time_exponent": {k: float(np.polyfit(n, np.log([r[f"{k}_s"] for r in last]), 1)[0])
                              for k in ("conic", "lower")},
            "all_certified": all(bool(r["bounds_certified"]) for r in ok),
            "contact_inside_every_gamma0": max(r["active_radius"] for r in ok) < min(r["gamma0_rim"] for r in ok)}


def run_family(family: str, sizes: list, folder: Path) -> dict:
    rows = []
    for size in sizes:
        mesh_file = str(write_punch_mesh(size, folder)) if FAMILIES[family]["mesh"] == "gmsh" else None
        row = {"size": size, **spawn("bounds", family, size, mesh_file)}
        if "error" not in row:
            low = spawn("lower", family, size, mesh_file)
            if "error" in low:
                row["error"] = f"lower: {low['error']}"
            else:
                row.update(lower_s=low["lower_s"], lower_peak_mb=low["lower_peak_mb"],
                           lower_alone=low["energy_lower"], lower_phases_s=low["phases_s"],
                           lower_start_mb=low["start_mb"])
        rows.append(row)
        shown = {k: row.get(k) for k in ("elements", "energy_gap_rel", "U_h", "U_lower", "U_upper", "conic_s",
                                         "lower_s", "error")}
        print(f"{family} {size}: {json.dumps(shown)}", flush=True)
    spec = FAMILIES[family]
    return {"label": spec["label"], "nested": spec.get("nested", False), "same_gamma0": spec.get("same_gamma0", False),
            "meshes": rows, "checks": family_checks(rows)}


def run_all(mode: str) -> dict:
    try:
        import gmsh  # noqa: F401
        have_gmsh = True
    except ImportError:
        have_gmsh = False
    out = {"mode": mode, "families": {}, "skipped": {}}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        for family, sizes in SIZES[mode].items():
            if FAMILIES[family]["mesh"] == "gmsh" and not have_gmsh:
                out["skipped"][family] = "gmsh is not installed (pip install '.[mesh]')"
                continue
            out["families"][family] = run_family(family, sizes, Path(tmp))
    out["total_s"] = time.perf_counter() - t0
    return out


# ----------------------------------------------------------------------------
# report and plots
# ----------------------------------------------------------------------------


def _f(v, fmt: str) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else format(v, fmt)


def render(res: dict) -> str:
    lines = [
        f"Mode `{res['mode']}`, total {res.get('total_s', 0) / 60:.1f} min. Each mesh: the (S) conic solve and "
        "`certified_bounds` in one process (the conic time and peak memory read before the bounds run), the "
        "lower-bound program alone in another. Times in seconds (wall clock), peak RSS in MB (about "
        f"{_start_mb(res):.0f} MB of it is Python and the imports). `gap` = (upper - lower) / |upper|; "
        "`stress` = sqrt(2 gap) / ||R(eps(v))||; `rim` = distance from the obstacle's axis to the edge of the "
        "mesh's Γ0; `active` = largest distance of an active contact node of U_h.", ""]
    for name, fam in res["families"].items():
        lines += [f"## {name}", "", fam["label"], "",
                  "| size | elements | lower | upper | gap | stress | cert. | U_h | U_lower | U_upper | conic s | "
                  "lower s | lower/conic | conic MB | lower MB | rim | active |",
                  "|" + "---|" * 17]
        for r in fam["meshes"]:
            if "error" in r:
                lines.append(f"| {r['size']} | error: {r['error']} |")
                continue
            lines.append(
                f"| {r['size']} | {r['elements']} | {r['energy_lower']:.7g} | {r['energy_upper']:.7g} | "
                f"{r['energy_gap_rel']:.3e} | {r['stress_error_bound_rel']:.3f} | {r['bounds_certified']} | "
                f"{r['U_h']:.6g} | {_f(r.get('U_lower'), '.6g')} | {_f(r.get('U_upper'), '.6g')} | "
                f"{r['conic_s']:.2f} | {r['lower_s']:.2f} | {r['lower_s'] / r['conic_s']:.0f} | "
                f"{r['conic_peak_mb']:.0f} | {r['lower_peak_mb']:.0f} | {r['gamma0_rim']:.3g} | "
                f"{r['active_radius']:.3g} |")
        c = fam["checks"]
        if not c:
            continue
        p, u, rt = c["pairs"], c["U"], c["rates"]
        if fam["same_gamma0"]:
            same = "every mesh has the same Γ0, so all meshes bound one Π*: a theorem (weak duality)"
        else:
            same = ("Γ0 is the union of the bottom facets within contact_radius and differs between meshes; "
                    + ("the contact set of every U_h lies inside every Γ0 (active < rim), so the problems plausibly "
                       "share Π*" if c["contact_inside_every_gamma0"] else
                       "on some mesh the contact set of U_h reaches the rim of Γ0 (active >= rim): those meshes "
                       "bound a different continuum problem") + ": an observation, not a theorem")
        # p_h = d p is the exponent in h only for (roughly) uniform refinement
        h_all, h_last = ("", "") if fam["nested"] else (f" (p_h = {rt['p_h_all']:.2f} in h)",
                                                          f" (p_h = {rt['p_h_last3']:.2f})")
        nested = ("nested meshes: a theorem (nested spaces, concavity)" if fam["nested"] else
                  "meshes not nested: an observation, not a theorem")
        lines += ["", f"- every bound certified: {c['all_certified']}.",
                  f"- weak duality across meshes: max lower {p['max_lower']:.7g} <= min upper {p['min_upper']:.7g} "
                  f"({p['pairs']} pairs, {len(p['violations'])} violations, smallest margin "
                  f"(upper_j - lower_i) / |upper_j| = {p['min_margin_rel']:.2e}); {same}.",
                  f"- U brackets against U_h of the same and every finer mesh: {u['inside']} of {u['checked']} "
                  f"inside ({nested}).",
                  f"- gap ~ elements^-p: p = {rt['p_all']:.3f} over all meshes{h_all}, "
                  f"{rt['p_last3']:.3f} over the last three{h_last}; per step p = "
                  + ", ".join(f"{v:.2f}" for v in rt["per_step"])
                  + ("" if fam["nested"] else  # local refinement: h does not halve uniformly
                     ", that is a drop by " + ", ".join(f"{v:.2f}" for v in rt["per_halving"]) + " per halving of h")
                  + "; measured drop per step " + ", ".join(f"{v:.2f}" for v in rt["factor"]) + ".",
                  "- lower-bound time / conic time: " + ", ".join(f"{v:.0f}" for v in c["time_ratio"])
                  + f"; time ~ elements^q over the last three meshes: q = {c['time_exponent']['conic']:.2f} (conic), "
                  f"{c['time_exponent']['lower']:.2f} (lower bound)."]
        lines.append("")
    for name, why in res.get("skipped", {}).items():
        lines.append(f"- {name} skipped: {why}")
    return "\n".join(lines) + "\n"


def _start_mb(res: dict) -> float:
    starts = [r["start_mb"] for fam in res["families"].values() for r in fam["meshes"] if "start_mb" in r]
    return float(np.median(starts)) if starts else float("nan")


def plots(res: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fams = {k: [r for r in v["meshes"] if "error" not in r] for k, v in res["families"].items()}
    fams = {k: v for k, v in fams.items() if v}
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for name, rows in fams.items():
        n = np.array([r["elements"] for r in rows], dtype=float)
        g = np.array([r["energy_gap_rel"] for r in rows])
        line, = ax.loglog(n, g, "o", label=name)
        rt = res["families"][name]["checks"].get("rates")
        if rt:
            # the least-squares line of p_all through the geometric means
            c = np.exp(np.mean(np.log(g)) + rt["p_all"] * np.mean(np.log(n)))
            ax.loglog(n, c * n ** -rt["p_all"], "--", color=line.get_color(),
                      label=f"fit: p = {rt['p_all']:.2f} (last three: {rt['p_last3']:.2f})")
    _save(fig, [ax], "relative energy gap (upper - lower) / |upper|", out / "gap.png", grid=True)

    cols = min(2, len(fams))
    fig, axes = plt.subplots(-(-len(fams) // cols), cols, figsize=(5.5 * cols, 4 * -(-len(fams) // cols)),
                             squeeze=False)
    for ax in axes.ravel()[len(fams):]:
        ax.set_visible(False)
    for ax, (name, rows) in zip(axes.ravel(), fams.items()):
        n = np.array([r["elements"] for r in rows], dtype=float)
        ax.semilogx(n, [r["U_h"] for r in rows], "k.-", label="U_h (discrete)")
        for r in rows:
            if r.get("U_lower") is not None:
                ax.plot([r["elements"]] * 2, [r["U_lower"], r["U_upper"]], "C0-", lw=3, alpha=0.6)
        ax.plot([], [], "C0-", lw=3, alpha=0.6, label="U bracket")
        ax.axhline(rows[-1]["U_h"], color="k", ls=":", lw=0.8)
        ax.set_title(name, fontsize=9)
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    _save(fig, axes.ravel()[:len(fams)], "U", out / "u_bracket.png")

    fig, (ax, mem) = plt.subplots(1, 2, figsize=(12, 4.5))
    for i, (name, rows) in enumerate(fams.items()):
        n = [r["elements"] for r in rows]
        for a, key in ((ax, "_s"), (mem, "_peak_mb")):
            a.loglog(n, [r["conic" + key] for r in rows], "o--", color=f"C{i}", label=f"{name}: (S) conic")
            a.loglog(n, [r["lower" + key] for r in rows], "s-", color=f"C{i}", label=f"{name}: lower bound")
    _save(fig, [ax], "seconds", out / "time.png", grid=True, fontsize=7, more=[(mem, "peak memory (MB)")])


def _save(fig, axes, ylabel: str, path: Path, grid: bool = False, fontsize: int = 8, more=()) -> None:
    """Label, legend and write a figure whose x axis is the number of elements
    (``more``: further ``(axes, ylabel)`` pairs)."""
    import matplotlib.pyplot as plt

    for ax, label in [(ax, ylabel) for ax in axes] + list(more):
        ax.set_xlabel("elements")
        ax.set_ylabel(label)
        if grid:
            ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=fontsize)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def measure(mode: str, out: Path) -> dict:
    from elastoplast.io.output import strict

    return strict(run_all(mode))


def main(argv=None) -> int:
    return run_record(__doc__, "small meshes, about a minute", HERE, TITLE, "bounds benchmark", measure, render, plots,
                      argv=argv, child=child)


if __name__ == "__main__":
    sys.exit(main())
