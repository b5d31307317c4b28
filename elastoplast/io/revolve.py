"""A revolved 3D view of a meridian-plane solution for ParaView (docs/indentation.md).

The meridian mesh (x = r >= 0, y = z) is swept about the axis x = 0 through
``n_sectors`` equal sectors: node (r, z) at angle theta becomes (r cos theta,
r sin theta, z) (nodes on the axis once), and each triangle becomes per sector a
wedge (VTK ``wedge``), or a pyramid when one of its nodes lies on the axis, or a
tetrahedron when two do. Their side faces are planar, so the view's volume is exactly
``n sin(2 pi / n) sum_T |T| r_T`` (r_T the centroid's radius), which tends to the
body of revolution's ``2 pi sum_T |T| r_T``.

Fields are carried over: point scalars copied, point vectors of two components
``(v_r, v_z)`` turned into ``(v_r cos theta, v_r sin theta, v_z)``, cell arrays
copied to every sector's cells of their triangle (tensors stay in the meridian's
(r, z, theta) frame). The view's size is capped: at most ``max_cells`` cells, the
sectors lowered to fit (never below :data:`MIN_SECTORS`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping

import numpy as np

from elastoplast.errors import InputError
from elastoplast.fem.material import von_mises
from elastoplast.io.output import mandel_to_tensor

#: the sectors of a full revolution by default, and the fewest a capped view keeps
N_SECTORS = 36
MIN_SECTORS = 8
#: the most cells a revolved view may hold (about 100 bytes of a VTU file each, with its fields)
MAX_CELLS = 2_000_000


def sectors_for(n_triangles: int, n_sectors: int = N_SECTORS, max_cells: int = MAX_CELLS) -> int:
    """The sectors the view uses: ``n_sectors`` lowered so that the cells fit in
    ``max_cells``; an :class:`InputError` on ``n_sectors`` when even :data:`MIN_SECTORS`
    would not fit (or ``n_sectors`` is below it)."""
    if not isinstance(n_sectors, int) or isinstance(n_sectors, bool) or n_sectors < MIN_SECTORS:
        raise InputError("n_sectors", f"must be an integer >= {MIN_SECTORS}, got {n_sectors!r}")
    fit = min(n_sectors, max_cells // max(n_triangles, 1))
    if fit < MIN_SECTORS:
        raise InputError("n_sectors", f"{n_triangles} triangles in {MIN_SECTORS} sectors exceed the view's cap of "
                                      f"{max_cells} cells: write the meridian plane (solution.vtu) only")
    return fit


def revolve_mesh(points: np.ndarray, cells: np.ndarray, n_sectors: int) -> tuple[np.ndarray, dict, np.ndarray,
                                                                                   np.ndarray]:
    """``(points3, blocks, node_of, angle_of)``: the revolved nodes; ``blocks[vtk_type] =
    (cells, triangle)`` with the source triangle of each cell; for each revolved node its
    meridian node and angle."""
    points = np.asarray(points, dtype=float)
    cells = np.asarray(cells, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] != 2 or cells.ndim != 2 or cells.shape[1] != 3:
        raise InputError("mesh", "a revolved view needs a 2D triangle mesh (the meridian plane)")
    if points[:, 0].min(initial=0.0) < 0:
        raise InputError("mesh", "a meridian mesh lies in x >= 0 (x is the radius)")
    n = points.shape[0]
    tol = 1e-12 * max(float(np.abs(points).max(initial=0.0)), 1.0)
    on_axis = points[:, 0] <= tol
    off = np.flatnonzero(~on_axis)
    theta = 2.0 * math.pi * np.arange(n_sectors) / n_sectors
    # numbering: axis nodes keep one copy (index = their meridian index's rank), off-axis nodes one per sector
    index = np.full((n, n_sectors), -1, dtype=np.int64)
    axis_nodes = np.flatnonzero(on_axis)
    index[axis_nodes, :] = np.arange(axis_nodes.size)[:, None]
    index[off, :] = axis_nodes.size + np.arange(off.size)[:, None] * n_sectors + np.arange(n_sectors)[None, :]
    node_of = np.concatenate([axis_nodes, np.repeat(off, n_sectors)])
    angle_of = np.concatenate([np.zeros(axis_nodes.size), np.tile(theta, off.size)])
    r, z = points[node_of, 0], points[node_of, 1]
    points3 = np.column_stack([r * np.cos(angle_of), r * np.sin(angle_of), z])
    # each triangle's nodes ordered: off-axis first (a wedge needs none on the axis; a pyramid's apex and a
    # tetrahedron's edge on the axis come last)
    count = on_axis[cells].sum(axis=1)
    order = np.argsort(on_axis[cells], axis=1, kind="stable")
    tri = np.take_along_axis(cells, order, axis=1)
    s0 = np.arange(n_sectors)
    s1 = (s0 + 1) % n_sectors
    blocks: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for kind, k in (("wedge", 0), ("pyramid", 1), ("tetra", 2)):
        sel = np.flatnonzero(count == k)
        if sel.size == 0:
            continue
        t = tri[sel]
        at = lambda col, s: index[t[:, col]][:, s]  # noqa: E731  (n_sel, n_sectors)
        if kind == "wedge":
            parts = [at(0, s0), at(1, s0), at(2, s0), at(0, s1), at(1, s1), at(2, s1)]
        elif kind == "pyramid":  # base quad a0 b0 b1 a1, apex on the axis
            parts = [at(0, s0), at(1, s0), at(1, s1), at(0, s1), at(2, s0)]
        else:  # c0 c1 and the axis edge a b
            parts = [at(0, s0), at(0, s1), at(1, s0), at(2, s0)]
        conn = np.stack(parts, axis=2).reshape(-1, len(parts))
        blocks[kind] = (conn, np.repeat(sel, n_sectors))
    return points3, blocks, node_of, angle_of


def orient(points3: np.ndarray, blocks: dict) -> dict:
    """The blocks with every cell positively oriented for VTK (a wedge's or pyramid's
    base and a tetrahedron's vertices reordered when their volume comes out negative)."""
    out = {}
    for kind, (conn, source) in blocks.items():
        conn = conn.copy()
        X = points3[conn]
        if kind == "wedge":
            normal = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
            flip = np.einsum("ij,ij->i", normal, X[:, 3] - X[:, 0]) < 0  # VTK: the first face's normal points to the second
            conn[flip] = conn[flip][:, [0, 2, 1, 3, 5, 4]]
        elif kind == "pyramid":
            normal = np.cross(X[:, 2] - X[:, 0], X[:, 3] - X[:, 1])
            flip = np.einsum("ij,ij->i", normal, X[:, 4] - X[:, 0]) < 0
            conn[flip] = conn[flip][:, [0, 3, 2, 1, 4]]
        else:
            flip = np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2)) < 0
            conn[flip] = conn[flip][:, [1, 0, 2, 3]]
        out[kind] = (conn, source)
    return out


def cell_volumes(points3: np.ndarray, blocks: dict) -> np.ndarray:
    """The volume of every revolved cell (split into tetrahedra; exact: the side faces are planar)."""
    splits = {"wedge": [(0, 1, 2, 3), (1, 2, 3, 4), (2, 3, 4, 5)], "pyramid": [(0, 1, 2, 4), (0, 2, 3, 4)],
              "tetra": [(0, 1, 2, 3)]}
    out = []
    for kind, (conn, _) in blocks.items():
        vol = np.zeros(conn.shape[0])
        for tet in splits[kind]:
            X = points3[conn[:, list(tet)]]
            vol += np.abs(np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2))) / 6.0
        out.append(vol)
    return np.concatenate(out) if out else np.zeros(0)


def write_revolved_vtu(path: str | Path, points: np.ndarray, cells: np.ndarray, *,
                       point_data: Mapping[str, np.ndarray] | None = None,
                       cell_data: Mapping[str, np.ndarray] | None = None,
                       n_sectors: int = N_SECTORS, max_cells: int = MAX_CELLS) -> int:
    """Write the revolved view of the meridian mesh and its fields (module docstring) as a
    VTU file; returns the sectors used."""
    import meshio

    cells = np.asarray(cells, dtype=np.int64)
    sectors = sectors_for(cells.shape[0], n_sectors, max_cells)
    points3, blocks, node_of, angle = revolve_mesh(points, cells, sectors)
    blocks = orient(points3, blocks)
    pdata = {}
    for name, values in (point_data or {}).items():
        v = np.asarray(values, dtype=float)[node_of]
        if v.ndim == 2 and v.shape[1] in (2, 3):  # (v_r, v_z[, 0]): turned with the node
            v = np.column_stack([v[:, 0] * np.cos(angle), v[:, 0] * np.sin(angle), v[:, 1]])
        pdata[name] = v
    cdata = {name: [np.asarray(values)[source] for _, source in blocks.values()]
             for name, values in (cell_data or {}).items()}
    meshio.write(Path(path), meshio.Mesh(points3, [(kind, conn) for kind, (conn, _) in blocks.items()],
                                         point_data=pdata, cell_data=cdata))
    return sectors


def write_revolved_solution(path: str | Path, disc, sol, n_sectors: int = N_SECTORS,
                            max_cells: int = MAX_CELLS) -> dict:
    """``solution_3d.vtu`` of an axisymmetric solution: the fields of ``solution.vtu``
    (displacement, contact pressure and force; stress in the meridian's frame, von Mises,
    xi, plastic) on the revolved view; returns ``{"file", "sectors"}``, or the reason the
    view was not written (``{"file": None, "reason"}``: beyond the cap)."""
    mesh = disc.mesh
    try:
        sectors = sectors_for(mesh.n_elements, n_sectors, max_cells)
    except InputError as exc:
        return {"file": None, "reason": str(exc)}
    pressure = np.zeros(mesh.n_nodes)
    pressure[disc.contact_nodes] = np.nan_to_num(sol.contact_pressure)
    force = np.zeros(mesh.n_nodes)
    force[disc.contact_nodes] = sol.contact_force
    write_revolved_vtu(path, mesh.points, mesh.cells,
                       point_data={"displacement": sol.u, "contact_pressure": pressure, "contact_force": force},
                       cell_data={"stress": mandel_to_tensor(sol.sigma).reshape(-1, 9), "von_mises": von_mises(sol.sigma),
                                  "xi": sol.xi, "plastic": sol.plastic.astype(np.int32)},
                       n_sectors=sectors, max_cells=max_cells)
    return {"file": Path(path).name, "sectors": sectors}
