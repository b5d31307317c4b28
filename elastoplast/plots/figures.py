"""Every picture the commands draw: convergence histories, certified gaps, adapted meshes coloured by their indicator, method comparisons."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from elastoplast.adapt.records import AdaptResult, Step, fitted_rate
from elastoplast.bounds.bracket import Bounds, element_indicators
from elastoplast.certificate.solution import Solution
from elastoplast.errors import InputError
from elastoplast.fem.discretize import Discretization
from elastoplast.io.store import atomic_write
from elastoplast.mesh.base import Mesh
from elastoplast.mesh.topology import local_edges, pair_keys, unique_rows


def plot_gap_curves(ax, curves: dict[str, list[Step] | tuple[Step, ...]], last: int | None = None) -> None:
    """The relative gap against the number of elements (log-log), one curve per
    sequence of steps, labelled with its fitted exponent (:func:`fitted_rate`
    over the ``last`` steps when given)."""
    styles = ["o-", "s--", "^-", "v-", "D:", "x--"]
    for (name, steps), style in zip(curves.items(), styles * 4):
        if not steps:
            continue
        ax.loglog([s.n_elements for s in steps], [s.gap_rel for s in steps], style, ms=4,
                  label=f"{name} (p = {fitted_rate(steps, last):.2f})")
    ax.set_xlabel("elements")
    ax.set_ylabel("relative energy gap (upper − lower) / |upper|")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)


def plot_gaps(path, adaptive: AdaptResult, uniform_run: AdaptResult | None, title: str = "") -> None:
    """The relative gap against the number of elements, adaptive and uniform (log-log)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.0, 4.2), layout="constrained")
    ax = fig.add_subplot()
    curves = {"adaptive": adaptive.steps}
    if uniform_run is not None:
        curves["uniform"] = uniform_run.steps
    plot_gap_curves(ax, curves)
    ax.set_title(title)
    fig.savefig(path, dpi=120)


def slice_polygons(mesh: Mesh, axis: int, value: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cut of a tetrahedral mesh by the plane ``x[axis] = value``.

    Returns ``(polygons (m, 4, 2), elements (m,), keys (m, 4))``: each cut
    tetrahedron's section (a triangle, its last vertex repeated, or a
    quadrilateral) in the plane's two other coordinates, in angular order; the
    tetrahedron's index; and for each vertex the mesh edge it lies on (one
    integer per edge, so that neighbours' sections share vertex keys exactly).
    A plane through mesh nodes (a symmetry plane, a layer of the grid) is moved
    by 1e-9 of the mesh size, into the mesh when it is a boundary plane, so that
    every section is a proper polygon; a face lying in the plane is drawn once (as
    the section of one of its tetrahedra), and tetrahedra touching the plane by an
    edge or a vertex only are left out.
    """
    p = mesh.points
    size = float(np.ptp(p, axis=0).max())
    lo, hi = float(p[:, axis].min()), float(p[:, axis].max())
    v = value + 1e-9 * size if value < hi - 1e-9 * size else hi - 1e-9 * size
    v = max(v, lo + 1e-9 * size)
    X = p[mesh.cells]
    dist = X[:, :, axis] - v
    exact = X[:, :, axis] - value
    on = np.abs(exact) <= 1e-12 * size
    # a tetrahedron with a face in the plane, or crossing it; not one touching it by an edge or a vertex only
    proper = (on.sum(axis=1) == 3) | ((exact < 0) & ~on).any(axis=1) & ((exact > 0) & ~on).any(axis=1)
    cut = np.flatnonzero((dist.min(axis=1) < 0) & (dist.max(axis=1) > 0) & proper)
    X, dist, cells = X[cut], dist[cut], mesh.cells[cut]
    a, b = local_edges(3).T
    da, db = dist[:, a], dist[:, b]
    cross = da * db < 0
    t = np.where(cross, da / np.where(cross, da - db, 1.0), 0.0)
    P = X[:, a] + t[..., None] * (X[:, b] - X[:, a])
    Q = P[:, :, [i for i in range(3) if i != axis]]
    keys = pair_keys(cells[:, a], cells[:, b], mesh.n_nodes)
    count = cross.sum(axis=1)
    centre = (Q * cross[..., None]).sum(axis=1) / count[:, None]
    angle = np.arctan2(Q[..., 1] - centre[:, None, 1], Q[..., 0] - centre[:, None, 0])
    order = np.argsort(np.where(cross, angle, np.inf), axis=1)[:, :4]
    Q = np.take_along_axis(Q, order[..., None], axis=1)
    keys = np.take_along_axis(keys, order, axis=1)
    tri = count == 3
    Q[tri, 3], keys[tri, 3] = Q[tri, 2], keys[tri, 2]
    return Q, cut, keys


def outline_segments(polygons: np.ndarray, keys: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """The segments ``(s, 2, 2)`` between polygons ``inside`` and polygons outside:
    the edges (pairs of vertex keys) met twice in all polygons and once among
    those inside."""
    k = polygons.shape[1]
    pair = np.sort(np.stack([keys, np.roll(keys, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    seg = np.stack([polygons, np.roll(polygons, -1, axis=1)], axis=2).reshape(-1, 2, 2)
    flag = np.repeat(inside, k)
    ok = pair[:, 0] != pair[:, 1]
    _, inv, count = unique_rows(pair[ok], int(keys.max(initial=0)) + 1)
    count_in = np.bincount(inv, weights=flag[ok], minlength=count.size)
    sel = (count[inv] == 2) & (count_in[inv] == 1) & flag[ok]
    return seg[ok][sel]


def draw_indicator(ax, disc: Discretization, solution: Solution, eta: np.ndarray, *, axis: int | None = None,
                   value: float = 0.0, window: tuple[float, float, float, float] | None = None, edges: bool = True):
    """Draw the mesh coloured by the indicator ``eta`` (one value per element,
    logarithmic colours), the outline of the plastic zone (black) and the active
    contact (red line, the contact edge marked by triangles).

    2D: the triangles in the (x, y) plane. 3D: the section of the mesh by the
    plane ``x[axis] = value`` (:func:`slice_polygons`; e.g. ``axis = 1, value = 0``
    for the symmetry plane y = 0 of the quarter model), drawn in the plane's two
    other coordinates. ``window = (x0, x1, y0, y1)`` zooms. Returns the polygon
    collection (for a colour bar)."""
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.colors import LogNorm

    mesh, d = disc.mesh, disc.dim
    eta = np.asarray(eta, dtype=float)
    if d == 2:
        polygons, elements, keys = mesh.points[mesh.cells], np.arange(mesh.n_elements), mesh.cells
        on_plane = np.ones(disc.n_contact, dtype=bool)
        plane = [0, 1]
    else:
        if axis is None:
            raise InputError("axis", "a 3D mesh is drawn as a section: give the axis normal to the plane")
        polygons, elements, keys = slice_polygons(mesh, axis, value)
        size = float(np.ptp(mesh.points, axis=0).max())
        on_plane = np.abs(mesh.points[disc.contact_nodes, axis] - value) <= 1e-9 * size
        plane = [i for i in range(3) if i != axis]
    positive = eta[eta > 0]
    top = float(positive.max()) if positive.size else 1.0
    floor = max(float(positive.min()) if positive.size else top, top * 1e-6)
    coll = PolyCollection(polygons, array=np.clip(eta[elements], floor, top), cmap="viridis",
                          norm=LogNorm(floor, top), edgecolors="k" if edges else "face",
                          linewidths=0.15 if edges else 0.0)
    ax.add_collection(coll)
    plastic = np.asarray(solution.plastic, dtype=bool)[elements]
    if plastic.any():
        ax.add_collection(LineCollection(outline_segments(polygons, keys, plastic), colors="k", linewidths=1.2,
                                         label="plastic zone"))
    active = np.asarray(solution.active, dtype=bool) & on_plane
    if active.any():
        xy = mesh.points[disc.contact_nodes[active]][:, plane]
        xy = xy[np.argsort(xy[:, 0])]
        ax.plot(xy[:, 0], xy[:, 1], "-", color="red", lw=3, solid_capstyle="butt", label="contact")
        ends = xy[[0, -1]]
        centre = disc.problem.obstacle.center[plane[0]] if disc.problem.obstacle.center else np.inf
        size = float(np.ptp(mesh.points, axis=0).max())
        ends = ends[np.abs(ends[:, 0] - centre) > 1e-9 * size]  # an end at the centre lies on a symmetry plane
        ax.plot(ends[:, 0], ends[:, 1], "^", color="red", ms=8, mec="k", label="contact edge")
    if window is None:
        lo, hi = polygons.reshape(-1, 2).min(axis=0), polygons.reshape(-1, 2).max(axis=0)
        window = (lo[0], hi[0], lo[1], hi[1])
    ax.set_xlim(window[0], window[1])
    ax.set_ylim(window[2], window[3])
    ax.set_aspect("equal")
    names = "xyz"
    ax.set_xlabel(names[plane[0]])
    ax.set_ylabel(names[plane[1]])
    return coll


def zoom_window(disc: Discretization, solution: Solution, *, axis: int | None = None,
                factor: float = 2.0) -> tuple[float, float, float, float]:
    """A window ``(x0, x1, y0, y1)`` for :func:`draw_indicator` around the contact and
    plastic zones: ``factor`` times their reach from the obstacle's centre (the
    contact zone's middle without one), sideways and in depth, clipped to the mesh."""
    plane = [0, 1] if disc.dim == 2 else [i for i in range(3) if i != axis]
    pts = disc.mesh.points
    contact = pts[disc.contact_nodes]
    centre_of = disc.problem.obstacle.center
    centre = float(centre_of[plane[0]]) if centre_of else float(0.5 * (contact[:, plane[0]].min()
                                                                        + contact[:, plane[0]].max()))
    base = float(contact[:, plane[1]].min())
    mid = pts[disc.mesh.cells].mean(axis=1)
    near = np.concatenate([contact[np.asarray(solution.active, dtype=bool)], mid[np.asarray(solution.plastic, dtype=bool)]])
    reach = max(float(np.abs(near[:, plane[0]] - centre).max(initial=0.0)),
                float(np.abs(near[:, plane[1]] - base).max(initial=0.0)))
    if reach <= 0:
        reach = float(np.ptp(contact[:, plane[0]]))
    x0 = max(float(pts[:, plane[0]].min()), centre - factor * reach)
    x1 = min(float(pts[:, plane[0]].max()), centre + factor * reach)
    return x0, x1, base, base + factor * reach


def plot_indicator(path, disc: Discretization, solution: Solution, bounds: Bounds, *, axis: int | None = None,
                   value: float = 0.0, title: str = "") -> None:
    """Two panels, the whole mesh and a zoom on the contact and plastic zones, of
    :func:`draw_indicator` with the marking indicator
    (:func:`~elastoplast.bounds.upper.element_indicators`). 3D: the section ``x[axis] =
    value`` (default: the plane y = 0 through the contact centre, a symmetry plane
    of the quarter model)."""
    from matplotlib.figure import Figure

    if disc.dim == 3 and axis is None:
        axis, value = 1, float(disc.problem.obstacle.center[1]) if disc.problem.obstacle.center else 0.0
    eta = element_indicators(disc, bounds)
    fig = Figure(figsize=(11.0, 4.4), layout="constrained")
    ax = fig.subplots(1, 2)
    coll = draw_indicator(ax[0], disc, solution, eta, axis=axis, value=value, edges=disc.n_elements < 20_000)
    draw_indicator(ax[1], disc, solution, eta, axis=axis, value=value,
                   window=zoom_window(disc, solution, axis=axis))
    ax[0].set_title(f"{disc.n_elements:,} elements" + (f", section {'xyz'[axis]} = {value:g}" if disc.dim == 3 else ""))
    ax[1].set_title("contact and plastic zones")
    ax[1].legend(loc="upper right", fontsize=8)
    fig.colorbar(coll, ax=ax, label="local gap (marking indicator)", shrink=0.9)
    if title:
        fig.suptitle(title)
    fig.savefig(path, dpi=130)


def plot_comparison(comparison, path: str | Path) -> None:
    """Errors (log scale) and time ratios per reference case of a :class:`~elastoplast.studies.compare.Comparison`,
    written as PNG."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in comparison.rows if r.get("U_rel") is not None]
    x = np.arange(len(rows))
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    floor = np.finfo(float).eps  # an exact match would vanish from a log axis
    ax1.semilogy(x, [max(r["U_rel"], floor) for r in rows], "o", label="U relative")
    ax1.semilogy(x, [max(r["sigma_rel"], floor) for r in rows], "s", label="σ energy relative")
    ax1.set(xlabel="reference case", ylabel="relative error (drawn at least at machine ε)",
            title=f"{comparison.method} against the references")
    ax1.legend()
    ax2.semilogy(x, [r["time_ratio"] for r in rows], "d")
    ax2.axhline(1.0, color="grey", lw=0.8)
    ax2.set(xlabel="reference case", ylabel=f"time {comparison.method} / time reference", title="time ratio")
    for ax in (ax1, ax2):
        ax.set_xticks(x, [r["case"][:6] for r in rows], rotation=90, fontsize=7)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    atomic_write(path, buf.getvalue())


def plot_convergence(path: str | Path, history: list[dict[str, Any]], title: str = "") -> bool:
    """Plot the KKT residuals of an iteration history against the iteration.

    Each history row may hold ``residuals`` (a dict name -> value, one curve
    each) and ``kkt_worst``; rows are placed at their ``iteration`` (else their
    index). Returns False, writing nothing, when no row has residuals.
    """
    from matplotlib.figure import Figure

    rows = [h for h in history if isinstance(h.get("residuals"), dict) or "kkt_worst" in h]
    if not rows:
        return False
    its = [h.get("iteration", i) for i, h in enumerate(rows)]
    fig = Figure(figsize=(6.4, 4.2), layout="constrained")
    ax = fig.add_subplot()
    curves = {name: [h.get("residuals", {}).get(name, np.nan) for h in rows]
              for name in sorted({k for h in rows for k in h.get("residuals", {})})}
    for name, vals in curves.items():
        ax.semilogy(its, _positive(vals), lw=1.0, label=name)
    if any("kkt_worst" in h for h in rows):
        worst = _positive([h.get("kkt_worst", np.nan) for h in rows])
        ax.semilogy(its, worst, "k--", lw=1.5, label="worst")
        if np.any(np.isfinite(worst)):  # show the worst residual's range, down to 1e-4 below its end
            ax.set_ylim(np.nanmin(worst) * 1e-4, np.nanmax(worst) * 10)
    ax.set_xlabel("iteration")
    ax.set_ylabel("relative KKT residual")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.savefig(Path(path), dpi=110)
    return True


def _positive(values: list[Any]) -> np.ndarray:
    """Values as floats with zeros and negatives as NaN (not drawn on a log axis)."""
    v = np.asarray(values, dtype=float)
    return np.where(v > 0, v, np.nan)


def plot_profile(profile: dict[str, list[float]], path: str | Path, *, taus: list[float], title: str = "") -> None:
    """Performance profiles (:func:`~elastoplast.studies.profiles.performance_profile`):
    one step curve per method, the fraction of instances solved within a factor τ of
    the best method against log2 τ, written as PNG."""
    import io

    from matplotlib.figure import Figure

    x = np.log2(np.asarray(taus, dtype=float))
    fig = Figure(figsize=(6.4, 4.4), layout="constrained")
    ax = fig.add_subplot()
    styles = ["-", "--", "-.", ":"]
    for i, (method, values) in enumerate(profile.items()):
        ax.step(x, values, where="post", ls=styles[i // 10 % len(styles)], lw=1.6, label=method)
    ax.set_xlim(0.0, max(float(x[-1]), 1.0) if x.size else 1.0)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("log2 τ  (time within a factor τ of the best method)")
    ax.set_ylabel("fraction of instances solved")
    ax.set_title(title or "performance profile")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    atomic_write(path, buf.getvalue())


def plot_path(path: str | Path, record: Mapping[str, Any], title: str = "") -> None:
    """``path.png``: F against U through the steps (the loop), each step a marker,
    unloading steps hollow; the residual imprint U_res of the first unloading marked on
    the U axis, the initial unloading slope S drawn from the peak down to F = 0, and the
    Oliver-Pharr power law fitted to the first unloading (when the summary has one)."""
    from matplotlib.figure import Figure

    steps = record["path"]
    U = [0.0] + [s["U"] for s in steps]
    F = [0.0] + [s["force"] for s in steps]
    fig = Figure(figsize=(6.4, 4.6), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(U, F, "-", color="0.3", lw=1.2, label="path (backward Euler steps)")
    load = [s for s in steps if not s["unloading"]]
    unload = [s for s in steps if s["unloading"]]
    ax.plot([s["U"] for s in load], [s["force"] for s in load], "o", color="C0", ms=4, label="loading step")
    ax.plot([s["U"] for s in unload], [s["force"] for s in unload], "o", mfc="none", color="C1", ms=5,
            label="unloading step")
    bad = [s for s in steps if s["status"] != "converged"]
    if bad:
        ax.plot([s["U"] for s in bad], [s["force"] for s in bad], "x", color="red", ms=9, label="not converged")
    slope = record.get("unloading_slope")
    if slope:
        u0 = slope["U_peak"] - slope["F_peak"] / slope["S"]
        ax.plot([slope["U_peak"], u0], [slope["F_peak"], 0.0], "--", color="C2", lw=1.2,
                label=f"initial unloading slope S = {slope['S']:.4g}")
    op = record.get("oliver_pharr")
    if op and op.get("alpha") is not None:  # the fitted power law, in the model's force
        h = np.linspace(max(op["h_f"], min(U)), op["h_max"], 60)
        ax.plot(h, op["force_share"] * op["alpha"] * (h - op["h_f"]) ** op["m"], "-", color="C4", lw=1.0,
                label=f"Oliver-Pharr fit: S = {op['S']:.4g}, E_r / E* = {op['E_r'] / op['E_star']:.3g}")
    imprint = record.get("residual_imprint")
    if imprint:
        ax.axvline(imprint["U"], color="C3", lw=0.8, ls=":")
        ax.plot([imprint["U"]], [imprint["force"]], "s", color="C3", ms=6,
                label=f"residual imprint U_res = {imprint['U']:.4g} (F = {imprint['force']:.3g})")
    ax.set_xlabel("U (rigid body's displacement)")
    ax.set_ylabel("F")
    ax.set_xlim(left=min(0.0, *U))
    ax.set_ylim(bottom=0.0)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    ax.set_title(title, fontsize=10)
    fig.savefig(path, dpi=120)
