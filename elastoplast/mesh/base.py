"""Simplicial meshes: built-in structured generators and files read by meshio.

A :class:`Mesh` holds node coordinates, simplices (triangles in 2D, tetrahedra in
3D) and named groups of boundary facets. The contact plane is ``x_d = 0`` with
the body above it (docs/math.md).
"""

from __future__ import annotations

import contextlib
import io
import itertools
import numbers
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, Sequence

import numpy as np

from elastoplast.limits import (as_path, check_input_file, check_memory, check_mesh_size, element_name, format_bytes,
    mesh_read_bytes, structured_counts)
from elastoplast.mesh.topology import boundary_facets, local_edges, locate_rows, unique_rows
from elastoplast.mesh.checks import check_conforming, check_facet_groups, merge_coincident_nodes, reorient
from elastoplast.errors import InputError
from elastoplast.errors import finite_float, short_repr


def read_only(a) -> np.ndarray:
    """A read-only view of ``a`` (the caller's own array stays as it was); an array that
    is already read-only is returned as it is, so that sealing twice keeps its identity."""
    if isinstance(a, np.ndarray) and not a.flags.writeable:
        return a
    view = np.asarray(a).view()
    view.flags.writeable = False
    return view


@dataclass(frozen=True)
class Mesh:
    """Nodes ``points (n_nodes, d)``, simplices ``cells (n_el, d+1)``, named
    facet groups ``groups[name] -> (n_facets, d)`` node indices.

    ``other_groups[name] -> dimension``: the named groups of a mesh file that are not
    facets (gmsh physical groups of the body, curves in 3D, points), kept only so that
    a boundary naming one is told what it named."""

    points: np.ndarray
    cells: np.ndarray
    groups: Mapping[str, np.ndarray] = field(default_factory=dict)
    other_groups: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # read-only views: an edit in place (mesh.points *= 2) would leave every operator built on them stale
        object.__setattr__(self, "points", read_only(self.points))
        object.__setattr__(self, "cells", read_only(self.cells))
        object.__setattr__(self, "groups", MappingProxyType(dict(self.groups)))
        object.__setattr__(self, "other_groups", MappingProxyType(dict(self.other_groups)))

    def __reduce__(self):
        # the read-only mappings (MappingProxyType) cannot be pickled: pickle plain dicts, rebuilt read-only on load
        return (Mesh, (self.points, self.cells, dict(self.groups), dict(self.other_groups)))

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
    if n < 2:  # one division: the two ends, whatever the clustering
        return np.array([lo, hi], dtype=float)
    if left <= 1e-14 * (hi - lo) or right <= 1e-14 * (hi - lo):
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

    Every argument is checked here (:func:`check_generator_arguments`), for Python
    callers and the ``[mesh]`` table alike: a bad one is an :class:`InputError`
    naming it as the table does (``mesh.divisions``, ...).
    """
    size, divisions, contact_radius, origin, contact_center, grading, pattern = check_generator_arguments(
        size, divisions, contact_radius, origin, contact_center, grading, pattern)
    dim = len(size)
    check_generator_size(divisions, pattern)
    toward = list(contact_center) + [0.0]
    axes = [
        graded_nodes(origin[a], origin[a] + size[a], int(divisions[a]), toward[a], grading)
        for a in range(dim)
    ]
    check_generator_grid(axes, size, divisions, origin, grading)
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

    facets = boundary_facets(cells)
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
# generator checks: sizes that fit in memory and grids that make usable elements
# ----------------------------------------------------------------------------

LENGTH_RANGE = (1e-50, 1e50)  # lengths in any unit; d-th powers and their products stay normal floats
MAX_ASPECT = 1e6  # element aspect ratio (largest over smallest grid spacing in one cell)
#: the shortest edge of a mesh, generated or read, must be at least this share of its largest
#: coordinate: a double keeps 16 digits, so a mesh far from the origin keeps about 7 of each
#: edge vector, which strains, volumes and the certificate's differences need
ROUND_OFF_SHARE = 1e-9


def _items(val: Any) -> list | None:
    """The entries of a list, tuple or one-dimensional array; None for anything else."""
    if isinstance(val, (list, tuple)) or (isinstance(val, np.ndarray) and val.ndim == 1):
        return list(val)
    return None


def finite_list(val: Any, n: int | tuple[int, ...], field: str) -> list[float]:
    """``val`` as a list of ``n`` (or one of the lengths ``n``) finite floats, else an
    :class:`InputError` naming ``field``."""
    counts = (n,) if isinstance(n, int) else n
    items = _items(val)
    floats = [finite_float(v) for v in items] if items is not None else []
    if len(floats) not in counts or any(v is None for v in floats):
        many = " or ".join(str(c) for c in counts)
        raise InputError(field, f"must be a list of {many} finite number(s), got {short_repr(val)}")
    return floats


def check_generator_arguments(size: Any, divisions: Any, contact_radius: Any, origin: Any, contact_center: Any,
                              grading: Any, pattern: Any) -> tuple:
    """The arguments of :func:`structured_mesh`, checked and normalised: ``(size, divisions,
    contact_radius, origin, contact_center, grading, pattern)`` with defaults filled in.

    ``size``: 2 or 3 positive lengths (the dimension); ``divisions``: as many positive
    integers; ``contact_radius``: finite and > 0; ``origin``: d finite numbers, the last 0
    (the body sits on the contact plane), default centred in x'; ``contact_center``:
    d - 1 finite numbers on the bottom face, default the origin of x'; ``grading``:
    finite and >= 1; ``pattern``: ``"diagonal"`` or, in 2D, ``"crossed"``. Each refusal
    is an :class:`InputError` naming ``mesh.<argument>``.
    """
    size = finite_list(size, (2, 3), "mesh.size")
    dim = len(size)
    if min(size) <= 0:
        raise InputError("mesh.size", f"{dim} positive lengths are required, got {short_repr(size)}")
    counts = _items(divisions)
    if (counts is None or len(counts) != dim
            or not all(isinstance(v, numbers.Integral) and not isinstance(v, (bool, np.bool_)) and v >= 1
                       for v in counts)):
        raise InputError("mesh.divisions", f"must be a list of {dim} positive integers, got {short_repr(divisions)}")
    divisions = [int(v) for v in counts]
    radius = finite_float(contact_radius)
    if radius is None:
        raise InputError("mesh.contact_radius", f"must be a finite number, got {short_repr(contact_radius)}")
    if not radius > 0:
        raise InputError("mesh.contact_radius", f"must be > 0, got {radius!r}")
    value = finite_float(grading)
    if value is None:
        raise InputError("mesh.grading", f"must be a finite number, got {short_repr(grading)}")
    if not value >= 1.0:
        raise InputError("mesh.grading", f"must be >= 1 (1 is uniform), got {value!r}")
    if not isinstance(pattern, str) or pattern not in ("diagonal", "crossed") or (pattern == "crossed" and dim == 3):
        raise InputError("mesh.pattern", f"must be 'diagonal' or (2D only) 'crossed', got {short_repr(pattern)}")
    if origin is None:
        origin = [-s / 2.0 for s in size[:-1]] + [0.0]
    else:
        origin = finite_list(origin, dim, "mesh.origin")
        if origin[-1] != 0.0:
            raise InputError("mesh.origin", "the body must sit on the contact plane: the last coordinate must be 0")
    if contact_center is None:
        center = [0.0] * (dim - 1)
    else:
        center = finite_list(contact_center, dim - 1, "mesh.contact_center")
        if any(not lo <= c <= lo + s for c, lo, s in zip(center, origin, size)):
            raise InputError("mesh.contact_center", f"{center} lies outside the bottom face "
                                                    f"{[[lo, lo + s] for lo, s in zip(origin[:-1], size)]}")
    return size, divisions, radius, origin, center, value, pattern


def check_resolved(shortest: float, magnitude: float, field: str, what: str, fix: str) -> None:
    """Refuse a mesh whose shortest length ``shortest`` (a grid spacing, an edge) is below
    :data:`ROUND_OFF_SHARE` of its largest coordinate ``magnitude``: the coordinates have
    lost it to round-off. One rule for generated meshes and mesh files."""
    if shortest < ROUND_OFF_SHARE * magnitude:
        raise InputError(field, f"{what} {shortest:.3g} is lost to round-off in coordinates of magnitude "
                                f"{magnitude:.3g} (lengths below {ROUND_OFF_SHARE:g} of it are not resolved): {fix}")


def check_generator_size(divisions: Sequence[int], pattern: str = "diagonal") -> None:
    """Refuse, before anything is allocated, divisions whose mesh and operators cannot
    fit in memory (:func:`elastoplast.mesh.checks.discretization_bytes`)."""
    n_nodes, n_elements, n_facets = structured_counts(divisions, pattern)
    shape = " x ".join(str(int(v)) for v in divisions)
    check_mesh_size(len(divisions), n_nodes, n_elements, n_facets, "mesh.divisions",
                    f"a {shape} grid", "use fewer divisions (or grading to refine only near the contact)")


def check_generator_grid(axes: Sequence[np.ndarray], size: Sequence[float], divisions: Sequence[int],
                         origin: Sequence[float], grading: float) -> None:
    """Refuse grids whose elements would be degenerate or hopelessly ill-conditioned.

    Each size must lie in ``LENGTH_RANGE``; grid spacings must be resolved by the
    coordinates (at least :data:`ROUND_OFF_SHARE` of their magnitude, the rule mesh
    files follow too: a far ``origin`` loses them to round-off); and no cell may be
    more than ``MAX_ASPECT`` times longer along one axis than along another (stiffness
    conditioning grows like its square). The field named is the one that made the grid
    so: ``mesh.size``, ``mesh.origin`` or ``mesh.grading``.
    """
    lo, hi = LENGTH_RANGE
    for s in size:
        if not lo <= s <= hi:
            raise InputError("mesh.size", f"lengths must lie between {lo:g} and {hi:g} (in any unit), got {list(size)}")
    spacing = [np.diff(a) for a in axes]
    magnitude = max(max(abs(o), abs(o + s)) for o, s in zip(origin, size))
    uniform = [s / int(n) for s, n in zip(size, divisions)]
    check_resolved(min(uniform), magnitude, "mesh.origin", "the grid spacing",
                   f"place the block near 0 (origin {list(origin)})")
    smallest = [float(h.min()) for h in spacing]
    largest = [float(h.max()) for h in spacing]
    aspect = max(largest[a] / smallest[b] if smallest[b] > 0 else np.inf
                 for a in range(len(axes)) for b in range(len(axes)) if a != b)
    if min(smallest) < ROUND_OFF_SHARE * magnitude or aspect > MAX_ASPECT:
        uniform_aspect = max(uniform) / min(uniform)
        what = (f"cells up to {aspect:.3g} times longer along one axis than another (at most {MAX_ASPECT:g}), "
                f"smallest spacing {min(smallest):.3g}")
        if grading > 1 and uniform_aspect <= MAX_ASPECT:
            raise InputError("mesh.grading", f"grading {grading:g} with divisions {list(divisions)} makes {what}: "
                                             "use a smaller grading")
        raise InputError("mesh.size", f"size {list(size)} with divisions {list(divisions)} makes {what}: make "
                                      "size / divisions similar along the axes")


# ----------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------

_BODY_TYPES = {2: "triangle", 3: "tetra"}
_FACET_TYPES = {2: "line", 3: "triangle"}
_IGNORED_TYPES = {2: {"vertex"}, 3: {"vertex", "line"}}  # gmsh physical points (and curves in 3D)
_UNTAGGED = "(untagged"  # facets without a tag (or gmsh physical tag 0): element faces, but in no group


def read_mesh(path: str | Path) -> Mesh:
    """Read a simplicial mesh with named facet groups from any file meshio reads.

    Facet groups come from gmsh physical groups (``field_data`` +
    ``gmsh:physical`` cell data) or, failing those, from any integer cell data
    on the facets. Nodes no simplex uses (gmsh writes geometry points too) are
    dropped and the rest renumbered. A 2D mesh must lie in ``z = 0``.

    What is read must be one connected, conforming body of linear simplices, else
    :class:`InputError` naming ``mesh.file``: other element types beside the
    simplices (quadrilaterals, hexahedra, prisms, pyramids, second-order elements),
    facets (lines in 2D, triangles in 3D) that are not boundary facets of the body,
    3D lines that are not element edges, separate parts, repeated elements,
    non-conforming or non-manifold meshes (:func:`elastoplast.mesh.checks.check_conforming`).
    Coincident nodes are merged, with a warning. The file size is checked against
    the memory available before reading, and the element count after.
    """
    path = as_path(path, "mesh.file", "mesh file")
    size = check_input_file(path, "mesh.file", "mesh file")
    check_memory(mesh_read_bytes(path, size), "mesh.file", f"reading {path} ({format_bytes(size)})",
                 "use a smaller mesh")
    m = _meshio_read(path)
    dim, body, facet_groups, lines, others = _cells_by_role(m, path)
    points = _mesh_points(m, dim, body, path)
    n_facets = sum(len(f) for f in facet_groups.values())
    check_mesh_size(dim, int(np.unique(body).size), len(body), n_facets, "mesh.file", f"the mesh in {path}",
                    "use a coarser mesh")

    used = np.unique(np.concatenate([body.ravel()] + [f.ravel() for f in facet_groups.values()]))
    target, _ = merge_coincident_nodes(points, used, "mesh.file")
    body = target[body]
    # drop nodes no simplex uses and renumber
    used = np.unique(body)
    renumber = -np.ones(points.shape[0], dtype=np.int64)
    renumber[used] = np.arange(used.size)
    groups = {}
    for name, facets in facet_groups.items():
        facets = renumber[target[facets]]
        if np.any(facets < 0):
            raise InputError("mesh.file", f"{path}: {int(np.any(facets < 0, axis=1).sum())} facet(s) of group "
                                          f"{name!r} are not faces of any {_BODY_TYPES[dim]} (they use nodes no "
                                          f"{_BODY_TYPES[dim]} uses)")
        groups[name] = facets
    untagged = {k: groups.pop(k) for k in [k for k in groups if k.startswith(_UNTAGGED)]}
    mesh = Mesh(points=points[used], cells=renumber[body], groups=groups, other_groups=others)
    uniq, counts = check_conforming(mesh.points, mesh.cells, "mesh.file")
    mesh = replace(mesh, cells=reorient(mesh.points, mesh.cells, "mesh.file"))
    check_facet_groups(uniq, counts, groups, mesh.n_nodes, "mesh.file")
    check_facet_groups(uniq, counts, untagged, mesh.n_nodes, "mesh.file", boundary_only=False)
    _check_lines_are_edges(mesh, renumber[target[lines]], path)
    return mesh


def _meshio_read(path: Path):
    """``meshio.read`` with every way it fails turned into one :class:`InputError`.

    meshio prints the reasons it could not read a file and then calls ``sys.exit(1)``
    (SystemExit), raises many exception types, and warns on stderr; its output is
    captured, and its warnings are passed on as warnings naming ``mesh.file``.
    """
    import meshio

    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = meshio.read(path)
    except (Exception, SystemExit) as exc:  # meshio ends with sys.exit(1) when no reader accepts the file
        if isinstance(exc, SystemExit):  # each reader's complaint was printed on stdout
            said = [line.strip() for line in out.getvalue().splitlines() if line.strip()]
            detail = "; ".join(dict.fromkeys(said)) or f"no reader for {path.suffix!r} files accepts it"
        else:
            detail = f"{type(exc).__name__}: {exc}"
        raise InputError("mesh.file", f"cannot read {path} as a mesh: {' '.join(detail.split())}"[:600]) from None
    for line in err.getvalue().splitlines():
        if "warning" in line.lower():
            warnings.warn(f"mesh.file: meshio: {line.strip()}", stacklevel=3)
    return m


def _cell_tags(m) -> tuple[str, list] | tuple[None, None]:
    """``(key, integer tags per cell block)``: gmsh's physical tags, else the first integer cell data."""
    for key in ["gmsh:physical"] + [k for k in m.cell_data if k != "gmsh:physical"]:
        data = m.cell_data.get(key)
        if data is None or len(data) != len(m.cells):
            continue
        arrays = [np.asarray(a) for a in data]
        if all(a.ndim == 1 and len(a) == len(b.data) and (a.dtype.kind in "iu" or (
                a.dtype.kind == "f" and np.all(np.isfinite(a)) and np.all(a == np.round(a))))
               for a, b in zip(arrays, m.cells)):
            return key, [a.astype(np.int64) for a in arrays]
    return None, None


def _cells_by_role(m, path: Path) -> tuple[int, np.ndarray, dict[str, np.ndarray], np.ndarray, dict[str, int]]:
    """``(dim, elements, facet groups by name, 3D lines, other named groups -> their dimension)``;
    refuses cell types it does not solve."""
    found: dict[str, int] = {}
    for block in m.cells:
        if len(block.data):
            found[block.type] = found.get(block.type, 0) + len(block.data)
    if "tetra" in found:
        dim = 3
    elif "triangle" in found:
        dim = 2
    else:
        listed = ", ".join(f"{n} {t}" for t, n in found.items()) or "no cells"
        raise InputError("mesh.file", f"{path} has no triangles or tetrahedra (found {listed}): elastoplast solves "
                                      "linear triangles (2D) or tetrahedra (3D) only (gmsh: first order, no "
                                      "recombination)")
    body_type, facet_type = _BODY_TYPES[dim], _FACET_TYPES[dim]
    other = {t: n for t, n in found.items() if t not in {body_type, facet_type} | _IGNORED_TYPES[dim]}
    if other:
        listed = ", ".join(f"{n} {t}" for t, n in other.items())
        raise InputError("mesh.file", f"{path} has {listed} cells beside its {found[body_type]} {body_type} cells: elastoplast "
                                      f"solves linear {element_name(dim)} only (boundary facets as "
                                      f"{facet_type}s); split or remesh them (gmsh: first order, no recombination)")
    blocks = [(b.type, np.asarray(b.data)) for b in m.cells]
    for kind, data in blocks:
        if data.ndim != 2 or data.dtype.kind not in "iu":
            raise InputError("mesh.file", f"{path}: the {kind} cells are not an integer table of node indices")
    body = np.concatenate([d for t, d in blocks if t == body_type]).astype(np.int64)
    lines = [d for t, d in blocks if t == "line" and dim == 3]
    lines = np.concatenate(lines).astype(np.int64) if lines else np.zeros((0, 2), dtype=np.int64)

    tag_key, tags = _cell_tags(m)
    tag_names: dict[tuple[int, int], str] = {}
    for name, data in (m.field_data or {}).items():
        data = np.asarray(data).ravel()
        if data.size >= 2 and data.dtype.kind in "iuf":
            tag_names[(int(data[1]), int(data[0]))] = str(name)
    lists: dict[str, list[np.ndarray]] = {}
    for i, (kind, data) in enumerate(blocks):
        if kind != facet_type:
            continue
        if tags is None:  # facets without tags belong to no group, but must still be boundary facets
            lists.setdefault(f"{_UNTAGGED} {facet_type}s)", []).append(data)
            continue
        for tag in np.unique(tags[i]):
            if tag == 0 and tag_key == "gmsh:physical":  # gmsh: in no physical group (Mesh.SaveAll)
                lists.setdefault(f"{_UNTAGGED} {facet_type}s)", []).append(data[tags[i] == tag])
                continue
            name = tag_names.get((dim - 1, int(tag)), str(int(tag)))
            lists.setdefault(name, []).append(data[tags[i] == tag])
    facet_groups = {name: np.concatenate(parts).astype(np.int64) for name, parts in lists.items()}
    others = {name: d for (d, _), name in tag_names.items() if d != dim - 1 and name not in facet_groups}
    n_points = len(m.points)
    for what, arr in [(body_type, body), ("line", lines)] + [(f"group {k!r}", v) for k, v in facet_groups.items()]:
        if arr.size and (arr.min() < 0 or arr.max() >= n_points):
            raise InputError("mesh.file", f"{path}: {what} cells refer to node {int(arr.max())} (or a negative "
                                          f"index) but the file has {n_points} nodes")
    return dim, body, facet_groups, lines, others


def _mesh_points(m, dim: int, body: np.ndarray, path: Path) -> np.ndarray:
    """Node coordinates, ``(n, dim)``: finite, planar in 2D, within ``LENGTH_RANGE``."""
    points = np.asarray(m.points)
    if points.ndim != 2 or points.shape[1] not in (2, 3) or points.dtype.kind not in "iuf":
        raise InputError("mesh.file", f"{path}: node coordinates must be a table of 2 or 3 numbers per node")
    points = points.astype(float)
    used = np.unique(body)
    if dim == 3 and points.shape[1] != 3:
        raise InputError("mesh.file", f"{path}: tetrahedra need 3 coordinates per node, the file has 2")
    if not np.all(np.isfinite(points[used])):
        bad = int(np.sum(~np.all(np.isfinite(points[used]), axis=1)))
        raise InputError("mesh.file", f"{path}: {bad} node(s) have coordinates that are not finite numbers")
    if dim == 2 and points.shape[1] == 3:
        if np.abs(points[used, 2]).max(initial=0.0) > 0.0:
            raise InputError("mesh.file", f"{path}: a triangle mesh must lie in the plane z = 0 (plane strain); a "
                                          "surface in space is no body (a 3D body needs tetrahedra)")
        points = np.ascontiguousarray(points[:, :2])
    extent = float(np.max(points[used].max(axis=0) - points[used].min(axis=0)))
    lo, hi = LENGTH_RANGE
    if not lo <= extent <= hi:
        raise InputError("mesh.file", f"{path}: the mesh extends over {extent:.3g}; lengths must lie between "
                                      f"{lo:g} and {hi:g} (in any unit)")
    check_resolved(shortest_edge(points, body), float(np.abs(points[used]).max()), "mesh.file",
                   f"{path}: the shortest edge", "translate the mesh near the origin (in x', and the obstacle's "
                                                 "center with it)")
    return points


def shortest_edge(points: np.ndarray, cells: np.ndarray) -> float:
    """The shortest edge of the simplices ``cells`` that has a positive length (inf if none):
    edges of length 0 are collapsed elements, which the conformity checks name."""
    shortest = np.inf
    for a, b in local_edges(points.shape[1]):
        length = np.sqrt(np.sum((points[cells[:, a]] - points[cells[:, b]]) ** 2, axis=1))
        shortest = min(shortest, float(length[length > 0].min(initial=np.inf)))
    return shortest


def _check_lines_are_edges(mesh: Mesh, lines: np.ndarray, path: Path) -> None:
    """Lines in a 3D file (gmsh physical curves) are ignored, but only if they are element edges."""
    if lines.size == 0:
        return
    if np.any(lines < 0):
        raise InputError("mesh.file", f"{path}: {int(np.any(lines < 0, axis=1).sum())} line cell(s) use nodes no "
                                      "tetrahedron uses (line elements are not solved)")
    edges, _, _ = unique_rows(np.sort(mesh.cells[:, local_edges(3)].reshape(-1, 2), axis=1), mesh.n_nodes)
    missing = locate_rows(edges, np.sort(lines, axis=1), mesh.n_nodes) < 0
    if np.any(missing):
        raise InputError("mesh.file", f"{path}: {int(missing.sum())} line cell(s) are not edges of any tetrahedron "
                                      "(line elements are not solved)")


def write_mesh(path: str | Path, mesh: Mesh) -> None:
    """Write ``mesh`` as a gmsh 2.2 file that :func:`read_mesh` (and gmsh, and any
    code reading gmsh physical groups) reads back: the simplices, and each facet
    group as a block of facets tagged with its own physical group (a facet in
    several groups is written once per group)."""
    import meshio

    d = mesh.dim
    facet_type = _FACET_TYPES[d]
    blocks = [(_BODY_TYPES[d], mesh.cells)]
    tags = [np.full(mesh.n_elements, len(mesh.groups) + 1, dtype=np.int32)]
    field_data = {"body": np.array([len(mesh.groups) + 1, d], dtype=np.int32)}
    for i, (name, facets) in enumerate(sorted(mesh.groups.items()), start=1):
        if len(facets) == 0:
            continue
        blocks.append((facet_type, np.asarray(facets)))
        tags.append(np.full(len(facets), i, dtype=np.int32))
        field_data[name] = np.array([i, d - 1], dtype=np.int32)
    points = mesh.points if d == 3 else np.column_stack([mesh.points, np.zeros(mesh.n_nodes)])
    out = meshio.Mesh(points, blocks, cell_data={"gmsh:physical": tags, "gmsh:geometrical": tags},
                      field_data=field_data)
    with contextlib.redirect_stdout(io.StringIO()):
        meshio.write(Path(path), out, file_format="gmsh22", binary=False)
