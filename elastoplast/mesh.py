"""Simplicial meshes: built-in structured generators and files read by meshio.

A :class:`Mesh` holds node coordinates, simplices (triangles in 2D, tetrahedra in
3D) and named groups of boundary facets. The contact plane is ``x_d = 0`` with
the body above it (MATH.md section 1).
"""

from __future__ import annotations

import contextlib
import io
import itertools
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Mapping, Sequence

import numpy as np

from .errors import InputError


@dataclass(frozen=True)
class Mesh:
    """Nodes ``points (n_nodes, d)``, simplices ``cells (n_el, d+1)``, named
    facet groups ``groups[name] -> (n_facets, d)`` node indices."""

    points: np.ndarray
    cells: np.ndarray
    groups: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "groups", MappingProxyType(dict(self.groups)))

    @property
    def dim(self) -> int:
        return self.points.shape[1]

    @property
    def n_nodes(self) -> int:
        return self.points.shape[0]

    @property
    def n_elements(self) -> int:
        return self.cells.shape[0]

    def group_nodes(self, names: Sequence[str]) -> np.ndarray:
        """Sorted unique node indices of the facets of the named groups."""
        if not names:
            return np.zeros(0, dtype=np.int64)
        return np.unique(np.concatenate([self.groups[n].ravel() for n in names]))


# ----------------------------------------------------------------------------
# structured generators
# ----------------------------------------------------------------------------


def graded_nodes(lo: float, hi: float, n: int, toward: float, grading: float) -> np.ndarray:
    """``n + 1`` nodes on ``[lo, hi]`` clustered toward ``toward`` by the power law
    ``x = toward + (end - toward) t**grading``, t uniform, on each side of it.

    ``grading = 1`` is uniform. When ``toward`` is inside the interval the
    divisions are shared between the two sides in proportion to their lengths,
    and ``toward`` itself is a node.
    """
    toward = min(max(toward, lo), hi)
    left, right = toward - lo, hi - toward
    if left <= 1e-14 * (hi - lo) or right <= 1e-14 * (hi - lo) or n < 2:
        end = hi if left <= right else lo
        t = np.linspace(0.0, 1.0, n + 1)
        x = toward + (end - toward) * t**grading
        return np.sort(x)
    n_left = int(round(n * left / (hi - lo)))
    n_left = min(max(n_left, 1), n - 1)
    t_left = np.linspace(0.0, 1.0, n_left + 1)
    t_right = np.linspace(0.0, 1.0, n - n_left + 1)
    xs_left = toward - left * t_left[::-1] ** grading
    xs_right = toward + right * t_right[1:] ** grading
    return np.concatenate([xs_left, xs_right])


def _structured_simplices(shape: tuple[int, ...], flip: list[np.ndarray]) -> np.ndarray:
    """Split every box of a tensor grid into d! simplices (Kuhn/Freudenthal).

    ``flip[a][i]`` reverses the diagonal direction along axis ``a`` in cell
    layer ``i``; reflecting per layer keeps the mesh conforming and lets it be
    mirror-symmetric about the contact centre.
    """
    dim = len(shape)
    strides = np.cumprod((1,) + tuple(s + 1 for s in shape[:-1]))
    idx = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), axis=-1).reshape(-1, dim)
    cells = []
    for perm in itertools.permutations(range(dim)):
        corners = [np.zeros_like(idx)]
        for axis in perm:
            step = corners[-1].copy()
            step[:, axis] += 1
            corners.append(step)
        verts = []
        for corner in corners:
            # reflect the offset along flipped axes: 0 <-> 1
            off = corner.copy()
            for a in range(dim):
                f = flip[a][idx[:, a]]
                off[:, a] = np.where(f, 1 - off[:, a], off[:, a])
            verts.append(((idx + off) * strides).sum(axis=1))
        cells.append(np.stack(verts, axis=1))
    return np.concatenate(cells, axis=0)


def _crossed_triangles(points: np.ndarray, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Four triangles per grid square, meeting at a new node in its centre."""
    nx, ny = shape
    i, j = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"))
    v00 = i + (nx + 1) * j
    corners = np.stack([v00, v00 + 1, v00 + nx + 2, v00 + nx + 1], axis=1)  # counter-clockwise
    centre = points.shape[0] + np.arange(i.size)
    points = np.concatenate([points, points[corners].mean(axis=1)])
    cells = np.concatenate([np.stack([centre, corners[:, a], corners[:, (a + 1) % 4]], axis=1) for a in range(4)])
    return points, cells


def _boundary_facets(cells: np.ndarray) -> np.ndarray:
    """Facets that belong to exactly one simplex, each row sorted.

    Each sorted facet is encoded as one integer in base ``n_nodes`` (when that
    fits in 63 bits, up to 2 million nodes in 3D) so that finding the facets seen
    once is a sort of integers, not of rows: 1 s instead of 10 s at a million
    tetrahedra. Larger meshes take the row-wise path.
    """
    dim = cells.shape[1] - 1
    faces = np.concatenate([np.delete(cells, i, axis=1) for i in range(dim + 1)], axis=0)
    faces.sort(axis=1)
    n = int(cells.max(initial=0)) + 1
    if dim * np.log2(max(n, 2)) < 62:
        keys = faces[:, 0].astype(np.int64)
        for j in range(1, dim):
            keys = keys * n + faces[:, j]
        order = np.argsort(keys, kind="stable")
        ks = keys[order]
        first = np.ones(ks.size, dtype=bool)
        first[1:] = ks[1:] != ks[:-1]
        starts = np.flatnonzero(first)
        counts = np.diff(np.append(starts, ks.size))
        return faces[order[starts[counts == 1]]]
    uniq, counts = np.unique(faces, axis=0, return_counts=True)
    return uniq[counts == 1]


def structured_mesh(
    size: Sequence[float],
    divisions: Sequence[int],
    contact_radius: float,
    *,
    origin: Sequence[float] | None = None,
    contact_center: Sequence[float] | None = None,
    grading: float = 1.0,
    pattern: str = "diagonal",
) -> Mesh:
    """Rectangle (2D) or box (3D) ``origin + [0, size]`` meshed into simplices.

    By default the block is centred in x' and sits on ``x_d = 0``. Groups:
    ``xmin, xmax`` (and ``ymin, ymax`` in 3D) for the sides, ``top`` and
    ``bottom`` for ``x_d = max`` and ``x_d = 0``, and ``contact``: the bottom
    facets lying within ``contact_radius`` of ``contact_center`` (a half-width
    in 2D). Nodes are graded toward the contact centre and the bottom.
    """
    dim = len(size)
    if origin is None:
        origin = [-s / 2.0 for s in size[:-1]] + [0.0]
    if contact_center is None:
        contact_center = [0.0] * (dim - 1)
    toward = list(contact_center) + [0.0]
    axes = [
        graded_nodes(origin[a], origin[a] + size[a], int(divisions[a]), toward[a], grading)
        for a in range(dim)
    ]
    # node index = i + (nx+1) j + (nx+1)(ny+1) k: flatten in Fortran order
    points = np.stack([g.ravel(order="F") for g in np.meshgrid(*axes, indexing="ij")], axis=1)
    shape = tuple(int(d) for d in divisions)
    flip = [0.5 * (axes[a][:-1] + axes[a][1:]) < toward[a] for a in range(dim)]
    if pattern == "crossed" and dim == 2:
        points, cells = _crossed_triangles(points, shape)
    else:
        cells = _structured_simplices(shape, flip)
    # reflected cells come out clockwise: swap two vertices to orient all alike
    X = points[cells]
    det = np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2))
    cells[det < 0, :2] = cells[det < 0, 1::-1]

    facets = _boundary_facets(cells)
    fx = points[facets]  # (nf, d, d)
    tol = 1e-9 * max(size)
    names = ["xmin", "xmax", "ymin", "ymax"][: 2 * (dim - 1)]
    groups: dict[str, np.ndarray] = {}
    for a in range(dim - 1):
        for name, val in ((names[2 * a], origin[a]), (names[2 * a + 1], origin[a] + size[a])):
            groups[name] = facets[np.all(np.abs(fx[:, :, a] - val) < tol, axis=1)]
    groups["bottom"] = facets[np.all(np.abs(fx[:, :, -1] - origin[-1]) < tol, axis=1)]
    groups["top"] = facets[np.all(np.abs(fx[:, :, -1] - origin[-1] - size[-1]) < tol, axis=1)]
    bottom = groups["bottom"]
    r = np.linalg.norm(points[bottom][:, :, :-1] - np.asarray(contact_center), axis=2)
    groups["contact"] = bottom[np.all(r <= contact_radius * (1 + 1e-12) + tol, axis=1)]
    return Mesh(points=points, cells=cells.astype(np.int64), groups=groups)


# ----------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------

_FACET_TYPES = {2: ("line",), 3: ("triangle",)}
_BODY_TYPES = {2: "triangle", 3: "tetra"}


def read_mesh(path: str | Path) -> Mesh:
    """Read a simplicial mesh with named facet groups from any file meshio reads.

    Facet groups come from gmsh physical groups (``field_data`` +
    ``gmsh:physical`` cell data) or, failing those, from any integer cell data
    on the facets. Nodes no simplex uses (gmsh writes geometry points too) are
    dropped and the rest renumbered. A 2D mesh must lie in ``z = 0``.
    """
    import meshio

    path = Path(path)
    if not path.is_file():
        raise InputError("mesh.file", f"mesh file not found: {path}")
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # meshio's gmsh reader prints a blank line
            m = meshio.read(path)
    except Exception as exc:  # meshio raises many types; the message is what matters
        raise InputError("mesh.file", f"cannot read {path}: {exc}") from None

    types = {block.type for block in m.cells}
    if "tetra" in types:
        dim = 3
    elif "triangle" in types:
        dim = 2
    else:
        raise InputError("mesh.file", f"{path} has no triangles or tetrahedra (found {sorted(types)})")
    body_type = _BODY_TYPES[dim]
    facet_type = _FACET_TYPES[dim][0]

    phys = m.cell_data.get("gmsh:physical")
    if phys is None:
        phys = next(iter(m.cell_data.values()), None)
    tag_names: dict[tuple[int, int], str] = {}
    for name, data in (m.field_data or {}).items():
        data = np.asarray(data).ravel()
        if data.size >= 2:
            tag_names[(int(data[1]), int(data[0]))] = name

    body = np.concatenate([b.data for b in m.cells if b.type == body_type], axis=0).astype(np.int64)
    facet_lists: dict[str, list[np.ndarray]] = {}
    if phys is not None:
        for block, tags in zip(m.cells, phys):
            if block.type != facet_type:
                continue
            tags = np.asarray(tags).astype(np.int64)
            for tag in np.unique(tags):
                name = tag_names.get((dim - 1, int(tag)), str(int(tag)))
                facet_lists.setdefault(name, []).append(block.data[tags == tag])

    points = np.asarray(m.points, dtype=float)
    if dim == 2:
        if points.shape[1] == 3:
            if np.abs(points[:, 2]).max(initial=0.0) > 0.0:
                raise InputError("mesh.file", f"{path}: a triangle mesh must lie in the plane z = 0")
            points = points[:, :2]
    # drop nodes no simplex uses and renumber
    used = np.unique(body)
    renumber = -np.ones(points.shape[0], dtype=np.int64)
    renumber[used] = np.arange(used.size)
    groups = {}
    for name, parts in facet_lists.items():
        facets = np.concatenate(parts, axis=0).astype(np.int64)
        if np.any(renumber[facets] < 0):
            raise InputError("mesh.file", f"{path}: facet group {name!r} uses nodes that belong to no {body_type}")
        groups[name] = renumber[facets]
    return Mesh(points=points[used], cells=renumber[body], groups=groups)
