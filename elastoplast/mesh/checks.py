"""Input checks that look at more than one value: files, memory, mesh topology, locking.

Every check raises :class:`InputError` naming the field the user wrote (``mesh.file``,
``mesh.divisions``, ``material.hardening``, ...) with a one-line message, or warns
(``warnings.warn``) where the input is legal but has been repaired or is questionable.
Everything here works on whole arrays (no loop over elements or nodes) and allocates
nothing before the memory checks have passed.
"""

from __future__ import annotations

import math
import os
import re
import resource
import stat
import warnings
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from elastoplast.errors import InputError

# ----------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------


def shown(path: Path) -> str:
    """A path for a one-line message (very long ones cut in the middle)."""
    text = str(path)
    return text if len(text) <= 200 else f"{text[:100]}...{text[-80:]}"


def as_path(path, field: str, what: str) -> Path:
    """``path`` as a :class:`Path`, or an InputError naming ``field`` when it is no path at all."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(field, f"expected a path to a {what}, got {type(path).__name__}")
    return Path(path)


def check_input_file(path: Path, field: str, what: str) -> int:
    """The size in bytes of ``path``, refusing what cannot be read as a file.

    Refused: a missing path, a directory, anything but a regular file (a FIFO or a
    device would block or never end), a file without read permission, an empty file.
    """
    try:
        st = path.stat()
    except (FileNotFoundError, NotADirectoryError):
        raise InputError(field, f"{what} not found: {shown(path)}") from None
    except ValueError:  # a NUL byte in the path
        raise InputError(field, f"invalid path {shown(path)!r}") from None
    except OSError as exc:
        raise InputError(field, f"cannot access {what} {shown(path)}: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(field, f"{shown(path)} is a directory, not a {what}")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(field, f"{shown(path)} is not a regular file (a device, pipe or socket cannot be a {what})")
    if not os.access(path, os.R_OK):
        raise InputError(field, f"{what} {shown(path)} cannot be read (permission denied)")
    if st.st_size == 0:
        raise InputError(field, f"{what} {shown(path)} is empty")
    return int(st.st_size)


def read_bytes(path: Path, field: str, what: str, limit: int) -> bytes:
    """The contents of ``path`` (at most ``limit`` bytes, else refused)."""
    size = check_input_file(path, field, what)
    if size > limit:
        raise InputError(field, f"{what} {path} has {format_bytes(size)}, more than the {format_bytes(limit)} "
                                f"a {what} may have")
    try:
        with open(path, "rb") as fh:
            return fh.read(limit + 1)
    except OSError as exc:
        raise InputError(field, f"cannot read {what} {path}: {exc.strerror or exc}") from None


# ----------------------------------------------------------------------------
# memory
# ----------------------------------------------------------------------------

MEMORY_ENV = "ELASTOPLAST_MEMORY_LIMIT"
_BYTE_UNITS = {"": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40, "p": 2**50}


def format_bytes(n: float) -> str:
    """``1536 -> '1.5 KiB'``."""
    for unit, size in (("PiB", 2**50), ("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def parse_bytes(text: str, field: str = MEMORY_ENV) -> int:
    """``'512M'``, ``'4 GiB'``, ``'1.5g'``, ``'1000000'`` -> bytes (binary units)."""
    m = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]*)?(?:e[+-]?[0-9]+)?)\s*([kmgtp]?)(?:i?b)?\s*", str(text).lower())
    if m is None:
        raise InputError(field, f"must be a size such as 4G, 512M or 1000000 (bytes), got {text!r}")
    value = float(m.group(1)) * _BYTE_UNITS[m.group(2)]
    if not (math.isfinite(value) and value >= 1):
        raise InputError(field, f"must be a positive size, got {text!r}")
    return int(value)


def _read_int(path: str) -> int | None:
    try:
        with open(path) as fh:
            text = fh.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _meminfo_available() -> int | None:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room() -> int | None:
    """Room left under a cgroup memory limit (v2, then v1), if there is one."""
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        limit, usage = _read_int(limit_file), _read_int(usage_file)
        if limit is not None and usage is not None and limit < 2**60:
            return max(limit - usage, 0)
    return None


def _rlimit_room() -> int | None:
    """Room left under ``ulimit -v`` (RLIMIT_AS), if set."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        with open("/proc/self/statm") as fh:
            used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        used = 0
    return max(soft - used, 0)


def available_memory() -> tuple[int | None, str]:
    """``(bytes, where the figure comes from)``; ``(None, ...)`` where unknown.

    ``ELASTOPLAST_MEMORY_LIMIT`` (e.g. ``4G``) wins; otherwise the smallest of
    ``MemAvailable`` (``/proc/meminfo``), the room under a cgroup limit and under
    ``ulimit -v``.
    """
    env = os.environ.get(MEMORY_ENV)
    if env is not None and env.strip():
        return parse_bytes(env), f"{MEMORY_ENV}={env.strip()}"
    found = [(v, name) for v, name in ((_meminfo_available(), "MemAvailable in /proc/meminfo"),
                                       (_cgroup_room(), "the cgroup memory limit"),
                                       (_rlimit_room(), "ulimit -v")) if v is not None]
    if not found:
        return None, "unknown"
    return min(found)


# Bytes per element of the mesh and discretisation build at its peak (measured, see
# discretization_bytes)
_BUILD_BYTES_PER_ELEMENT = {2: 770, 3: 1650}
# meshio's peak while reading, per byte of file, by suffix (measured, see mesh_read_bytes)
MESH_READ_FACTORS = {".msh": 8, ".vtk": 4, ".vtu": 16}
MESH_READ_DEFAULT_FACTOR = 16
# An element count beyond any machine, refused without further arithmetic.
MAX_ELEMENTS = 2**40


def discretization_bytes(dim: int, n_nodes: int, n_elements: int, n_facets: int = 0) -> int:
    """Estimated peak memory (bytes) of building a mesh and its :class:`Discretization`.

    Since B is written directly as CSR with 32-bit indices, in chunks of elements
    (:func:`~elastoplast.fem.discretize.free_strain_operator`), no array of the build
    grows faster than the element count, and the peak is a constant per element
    (:data:`_BUILD_BYTES_PER_ELEMENT`) plus the points and facet groups (8d bytes
    each). The constants are the largest measured: tracemalloc's peak of
    ``problem_from_dict`` + ``discretize`` on the shipped graded rectangles and boxes
    was 754, 751 and 575 bytes per triangle (3,600, 57,600 and 230,400 triangles)
    and 1,528, 1,612 and 1,223 bytes per tetrahedron (5,184, 41,472 and 192,000),
    falling as the fixed-size chunks weigh less; ``tests/test_inputs.py`` checks the
    estimate against tracemalloc's peak on every run. The solvers need several times
    more than this; it is a floor, not a budget.
    """
    d = int(dim)
    return int(_BUILD_BYTES_PER_ELEMENT[d] * int(n_elements) + 8 * d * (int(n_nodes) + int(n_facets)))


def mesh_read_bytes(path: Path, size: int) -> int:
    """Estimated peak memory of ``meshio.read`` on a file of ``size`` bytes.

    Peak RSS increase / file size, measured with meshio 5.3.5 (``benchmarks/memory``,
    160k triangles and 192k tetrahedra with facet groups): gmsh 2.2 ASCII 4.9 (2D) and
    7.0 (3D), binary 3.8 and 3.8; VTU base64 + zlib 13.5 and 12.8, VTU ASCII 10.3 and
    13.4; VTK binary 1.9 and 2.1, ASCII 2.2 and 2.7. The factors (``MESH_READ_FACTORS``:
    8 for ``.msh``, 4 for ``.vtk``, 16 for ``.vtu`` and any other suffix) are these
    maxima with a margin. A compressed file can inflate far more (a zlib bomb): that
    is not bounded here.
    """
    return MESH_READ_FACTORS.get(path.suffix.lower(), MESH_READ_DEFAULT_FACTOR) * int(size)


def check_memory(need: int, field: str, what: str, advice: str) -> None:
    """Refuse when ``need`` bytes exceed the memory available now."""
    limit, source = available_memory()
    if limit is not None and need > limit:
        raise InputError(field, f"{what} needs about {format_bytes(need)}, more than the {format_bytes(limit)} "
                                f"available ({source}); {advice}")


def element_name(dim: int) -> str:
    return {2: "triangles", 3: "tetrahedra"}[dim]


def check_mesh_size(dim: int, n_nodes: int, n_elements: int, n_facets: int, field: str, what: str,
                    advice: str) -> None:
    """Refuse a mesh whose discretisation cannot fit in memory, before it is built."""
    if n_elements > MAX_ELEMENTS:
        raise InputError(field, f"{what} would have {n_elements:.3g} {element_name(dim)}: far beyond any memory; "
                                f"{advice}")
    check_memory(discretization_bytes(dim, n_nodes, n_elements, n_facets), field,
                 f"{what} ({n_elements:,} {element_name(dim)}, {n_nodes:,} nodes; mesh and operators)", advice)


def structured_counts(divisions: Sequence[int], pattern: str = "diagonal") -> tuple[int, int, int]:
    """``(n_nodes, n_elements, n_boundary_facets)`` of :func:`structured_mesh`, in exact
    integers (nothing is allocated, so absurd divisions cost nothing)."""
    div = [int(v) for v in divisions]
    dim = len(div)
    n_nodes = math.prod(v + 1 for v in div)
    if dim == 2:
        nx, ny = div
        crossed = pattern == "crossed"
        return n_nodes + (nx * ny if crossed else 0), (4 if crossed else 2) * nx * ny, 2 * (nx + ny)
    nx, ny, nz = div
    return n_nodes, 6 * nx * ny * nz, 4 * (nx * ny + ny * nz + nx * nz)


# ----------------------------------------------------------------------------
# mesh topology (files): one connected, conforming body
# ----------------------------------------------------------------------------

MERGE_TOLERANCE = 1e-10  # coincident nodes: closer than this times the mesh extent


def unique_rows(a: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(unique rows, inverse, counts)`` of an integer array with entries in ``[0, n)``.

    Rows are encoded as one int64 key each when ``n**width`` fits (much faster than
    ``np.unique(axis=0)``), otherwise compared as rows.
    """
    a = np.ascontiguousarray(a, dtype=np.int64)
    if a.shape[0] == 0:
        return a, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    if max(int(n), 1) ** a.shape[1] < 2**62:
        key = a[:, 0].copy()
        for j in range(1, a.shape[1]):
            key = key * int(n) + a[:, j]
        _, first, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
        return a[first], inverse.ravel(), counts
    uniq, inverse, counts = np.unique(a, axis=0, return_inverse=True, return_counts=True)
    return uniq, inverse.ravel(), counts


def locate_rows(table: np.ndarray, queries: np.ndarray, n: int) -> np.ndarray:
    """Index in ``table`` (unique rows) of each row of ``queries``, -1 where absent."""
    both = np.concatenate([table, queries]).astype(np.int64)
    _, inverse, _ = unique_rows(both, n)
    where = np.full(inverse.max(initial=-1) + 1, -1, dtype=np.int64)
    where[inverse[: len(table)]] = np.arange(len(table))
    return where[inverse[len(table):]]


def merge_coincident_nodes(points: np.ndarray, used: np.ndarray, field: str) -> tuple[np.ndarray, int]:
    """Map each node to one representative of the nodes at its position.

    Only the ``used`` nodes are compared (gmsh keeps geometry points that no element
    uses). Nodes closer than ``MERGE_TOLERANCE`` times the extent of the used nodes
    are one node: separate copies of the nodes on an interface (two volumes meshed
    without sharing their surface) leave the parts unconnected, which would be solved
    as separate bodies. Returns ``(target, n_merged)``, ``target[i]`` the smallest
    index at node i's position; warns, naming ``field``, when any are merged.
    """
    from scipy.spatial import cKDTree

    target = np.arange(points.shape[0])
    if used.size < 2:
        return target, 0
    P = points[used]
    extent = float(np.max(P.max(axis=0) - P.min(axis=0)))
    tol = MERGE_TOLERANCE * extent
    pairs = cKDTree(P).query_pairs(tol, output_type="ndarray") if extent > 0 else np.zeros((0, 2), dtype=np.int64)
    if pairs.size == 0 and extent > 0:
        return target, 0
    if extent == 0:  # every node at one point
        pairs = np.stack([np.zeros(used.size - 1, dtype=np.int64), np.arange(1, used.size)], axis=1)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(used.size, used.size))
    n_groups, labels = connected_components(graph, directed=False)
    first = np.full(n_groups, used.size, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(used.size))
    target[used] = used[first[labels]]
    n_merged = used.size - n_groups
    warnings.warn(f"{field}: merged {n_merged} coincident node(s) into others (nodes closer than "
                  f"{MERGE_TOLERANCE:g} x the mesh extent {extent:.4g} are one node)", stacklevel=3)
    return target, n_merged


def element_facets(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All facets of all elements, each row sorted: ``(facets (n_el*(d+1), d),
    element of each, local index of the vertex each is opposite to)``; facet ``j`` of
    element ``e`` is row ``j * n_el + e``."""
    n, q = cells.shape
    facets = np.sort(np.concatenate([np.delete(cells, i, axis=1) for i in range(q)], axis=0), axis=1)
    return facets, np.tile(np.arange(n), q), np.repeat(np.arange(q), n)


def boundary_facets(cells: np.ndarray, n_nodes: int | None = None) -> np.ndarray:
    """Facets that belong to exactly one element, each row sorted."""
    facets, _, _ = element_facets(cells)
    uniq, _, counts = unique_rows(facets, int(cells.max(initial=0)) + 1 if n_nodes is None else n_nodes)
    return uniq[counts == 1]


def _outward_normals(points: np.ndarray, cells: np.ndarray, elements: np.ndarray, local: np.ndarray,
                     facets: np.ndarray) -> np.ndarray:
    """Unit normals of ``facets`` pointing away from the vertex ``local`` of ``elements``."""
    X = points[facets]
    d = points.shape[1]
    if d == 2:
        t = X[:, 1] - X[:, 0]
        nrm = np.stack([t[:, 1], -t[:, 0]], axis=1)
    else:
        nrm = np.cross(X[:, 1] - X[:, 0], X[:, 2] - X[:, 0])
    opposite = points[cells[elements, local]]
    flip = np.einsum("ij,ij->i", opposite - X[:, 0], nrm) > 0
    nrm[flip] *= -1
    return nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), np.finfo(float).tiny)


def check_conforming(points: np.ndarray, cells: np.ndarray, field: str) -> tuple[np.ndarray, np.ndarray]:
    """Refuse a mesh that is not one connected, conforming body; return the unique
    facets and how many elements share each (1 on the boundary, 2 inside).

    In a conforming simplicial mesh of one body, (1) no element is repeated and none
    has two vertices at one node, (2) every facet belongs to one element (boundary) or
    two (interior), (3) the elements are connected through shared facets, (4) each
    ridge of the boundary (a vertex in 2D, an edge in 3D) lies on exactly two boundary
    facets, which (5) do not fold onto each other (opposite normals, overlapping), and
    (6) no node lies on a boundary facet it is not a vertex of. Hanging nodes and
    interfaces meshed differently on their two sides fail (4), (5) or (6); separate
    parts, or parts touching only at a vertex or an edge, fail (3).
    """
    n_nodes = points.shape[0]
    d = points.shape[1]
    n_el = cells.shape[0]
    sorted_cells = np.sort(cells, axis=1)
    collapsed = np.any(sorted_cells[:, 1:] == sorted_cells[:, :-1], axis=1)
    if np.any(collapsed):
        bad = np.flatnonzero(collapsed)
        raise InputError(field, f"{bad.size} element(s) use one node twice (e.g. element {bad[0]}, nodes "
                                f"{cells[bad[0]].tolist()})")
    _, _, counts = unique_rows(sorted_cells, n_nodes)
    if np.any(counts > 1):
        raise InputError(field, f"{int(np.sum(counts - 1))} element(s) repeat another element's nodes "
                                "(each element must appear once)")
    facets, owner, local = element_facets(cells)
    uniq, inverse, counts = unique_rows(facets, n_nodes)
    if np.any(counts > 2):
        bad = np.flatnonzero(counts > 2)
        raise InputError(field, f"{bad.size} facet(s) are shared by 3 or more elements (overlapping or "
                                f"non-manifold elements), e.g. nodes {uniq[bad[0]].tolist()}")
    _check_connected(cells, owner, inverse, counts, n_nodes, field)
    boundary = counts[inverse] == 1
    bfacets, bowner, blocal = facets[boundary], owner[boundary], local[boundary]
    normals = _outward_normals(points, cells, bowner, blocal, bfacets)
    _check_boundary_ridges(points, bfacets, normals, n_nodes, field)
    _check_hanging_nodes(points, bfacets, field)
    return uniq, counts


def _check_connected(cells, owner, inverse, counts, n_nodes, field) -> None:
    """One body: the elements connected through shared facets."""
    n_el = cells.shape[0]
    interior = counts[inverse] == 2
    order = np.argsort(inverse[interior], kind="stable")
    pairs = owner[interior][order].reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n_el, n_el))
    n_parts, labels = connected_components(graph, directed=False)
    if n_parts == 1:
        return
    sizes = np.sort(np.bincount(labels))[::-1]
    shown = ", ".join(str(s) for s in sizes[:5]) + (", ..." if n_parts > 5 else "")
    # do the parts share nodes? then they touch at vertices or edges only
    node_part = np.full(n_nodes, -1)
    node_part[cells.ravel()] = np.repeat(labels, cells.shape[1])
    shared = np.any(node_part[cells] != labels[:, None])
    if shared:
        raise InputError(field, f"the mesh is {n_parts} parts ({shown} elements) that share nodes but no facet: they "
                                "touch only at vertices or edges, or meet at a non-conforming interface (hanging nodes, "
                                "faces split differently); it must be one body whose elements meet through shared "
                                "facets")
    raise InputError(field, f"the mesh has {n_parts} disconnected parts ({shown} elements); elastoplast solves one "
                            "body pressed by one rigid body: remove the extra parts, or mesh touching parts "
                            "conformally (gmsh: fragment the volumes so they share their interface)")


def _check_boundary_ridges(points, bfacets, normals, n_nodes, field) -> None:
    """(4) each boundary ridge on exactly two boundary facets, (5) without a fold."""
    d = points.shape[1]
    k = bfacets.shape[1]  # d nodes per facet; ridges are its (d-1)-subsets
    ridges = np.sort(np.concatenate([np.delete(bfacets, i, axis=1) for i in range(k)], axis=0), axis=1)
    which = np.tile(np.arange(len(bfacets)), k)
    uniq, inverse, counts = unique_rows(ridges, n_nodes)
    ridge_name = "boundary node(s)" if d == 2 else "boundary edge(s)"
    if np.any(counts != 2):
        bad = np.flatnonzero(counts != 2)
        found = sorted(set(counts[bad].tolist()))
        raise InputError(field, f"the boundary is not a closed surface: {bad.size} {ridge_name} lie on "
                                f"{'/'.join(map(str, found))} boundary facets instead of 2, e.g. nodes "
                                f"{uniq[bad[0]].tolist()} (hanging nodes, an interface meshed differently on its "
                                "two sides, or parts touching along an edge)")
    order = np.argsort(inverse, kind="stable")
    pairs = which[order].reshape(-1, 2)
    cos = np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]])
    folded = cos < -1.0 + 1e-8
    if np.any(folded):
        bad = np.flatnonzero(folded)
        raise InputError(field, f"the boundary folds back onto itself at {bad.size} {ridge_name} (two boundary facets "
                                f"overlap with opposite normals), e.g. nodes {uniq[bad[0]].tolist()}: the mesh is not "
                                "conforming (hanging nodes, or faces split differently on the two sides of an "
                                "interface)")


def _check_hanging_nodes(points, bfacets, field, n_candidates: int = 8, tol: float = 1e-8) -> None:
    """(6) no boundary node lies on a boundary facet it is not a vertex of.

    For each boundary facet the ``d + n_candidates`` boundary nodes nearest its
    centroid (k-d tree) are tested: distance to the facet's line/plane at most
    ``tol`` times its longest edge, and barycentric coordinates within ``[-tol, 1 + tol]``.
    """
    from scipy.spatial import cKDTree

    d = points.shape[1]
    bnodes = np.unique(bfacets)
    if bnodes.size <= d:
        return
    X = points[bfacets]  # (nf, d, d)
    centroid = X.mean(axis=1)
    radius = np.linalg.norm(X - centroid[:, None], axis=2).max(axis=1)
    k = min(bnodes.size, d + n_candidates)
    dist, idx = cKDTree(points[bnodes]).query(centroid, k=k)
    cand = bnodes[idx]  # (nf, k)
    ok = (dist <= radius[:, None] * (1 + 1e-9)) & ~np.any(cand[:, :, None] == bfacets[:, None, :], axis=2)
    f, j = np.nonzero(ok)
    if f.size == 0:
        return
    q = points[cand[f, j]]
    P = X[f]
    e = [P[:, i] - P[:, 0] for i in range(1, d)]
    w = q - P[:, 0]
    h = np.max([np.linalg.norm(P[:, a] - P[:, b], axis=1) for a in range(d) for b in range(a)], axis=0)
    if d == 2:
        t = np.einsum("ij,ij->i", w, e[0]) / np.einsum("ij,ij->i", e[0], e[0])
        off = np.linalg.norm(w - t[:, None] * e[0], axis=1)
        bary = np.stack([1 - t, t], axis=1)
    else:
        g11, g12, g22 = (np.einsum("ij,ij->i", a, b) for a, b in ((e[0], e[0]), (e[0], e[1]), (e[1], e[1])))
        r1, r2 = np.einsum("ij,ij->i", w, e[0]), np.einsum("ij,ij->i", w, e[1])
        det = g11 * g22 - g12 * g12
        s = (g22 * r1 - g12 * r2) / det
        t = (g11 * r2 - g12 * r1) / det
        off = np.linalg.norm(w - s[:, None] * e[0] - t[:, None] * e[1], axis=1)
        bary = np.stack([1 - s - t, s, t], axis=1)
    hanging = (off <= tol * h) & np.all(bary >= -tol, axis=1)
    if np.any(hanging):
        first = np.flatnonzero(hanging)[0]
        node = int(cand[f[first], j[first]])
        raise InputError(field, f"{np.unique(cand[f, j][hanging]).size} node(s) hang on boundary facets they are not "
                                f"vertices of, e.g. node {node} at {points[node].tolist()} on facet "
                                f"{bfacets[f[first]].tolist()}: the mesh is not conforming")


def check_facet_groups(uniq: np.ndarray, counts: np.ndarray, groups: Mapping[str, np.ndarray], n_nodes: int,
                       field: str, boundary_only: bool = True) -> None:
    """Every facet of every group must be a boundary facet of the body (with
    ``boundary_only=False``, a face of some element: facets in no group are ignored,
    but a facet that is no face would be an element silently dropped)."""
    for name, facets in groups.items():
        if len(facets) == 0:
            continue
        where = locate_rows(uniq, np.sort(facets, axis=1), n_nodes)
        missing = where < 0
        if np.any(missing):
            raise InputError(field, f"{int(missing.sum())} facet(s) of group {name!r} are not faces of any element, "
                                    f"e.g. nodes {facets[np.flatnonzero(missing)[0]].tolist()}")
        inside = counts[where] == 2
        if boundary_only and np.any(inside):
            raise InputError(field, f"{int(inside.sum())} facet(s) of group {name!r} lie inside the body (between two "
                                    "elements); boundary conditions act on boundary facets only")


# ----------------------------------------------------------------------------
# perfect plasticity on meshes that lock
# ----------------------------------------------------------------------------

CROSSED_TOLERANCE = 1e-6  # |sin| of the angle between the two halves of a crossing line


def crossed_centres(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Nodes that are the centre of a crossed quadrilateral (boolean per node).

    A criss-cross centre is an interior node of exactly four triangles whose four
    edges lie on two straight lines (its quadrilateral's diagonals): around such a
    "singular vertex" the divergences of P1 fields on the four triangles satisfy one
    linear relation, which is what keeps the crossed pattern free of locking under
    plastic incompressibility. Boundary nodes are never centres (a half-crossed
    quadrilateral on the boundary has no such relation).
    """
    n = points.shape[0]
    degree = np.bincount(cells.ravel(), minlength=n)
    on_boundary = np.zeros(n, dtype=bool)
    on_boundary[boundary_facets(cells, n).ravel()] = True
    candidate = (degree == 4) & ~on_boundary
    if not np.any(candidate):
        return candidate
    edges = np.concatenate([cells[:, [a, b]] for a in range(3) for b in range(3) if a != b], axis=0)
    edges = edges[candidate[edges[:, 0]]]
    edges, _, _ = unique_rows(edges, n)  # sorted by centre, then neighbour
    per_centre = np.bincount(edges[:, 0], minlength=n)
    candidate &= per_centre == 4
    edges = edges[candidate[edges[:, 0]]]
    centres = edges[::4, 0]
    v = (points[edges[:, 1]] - points[edges[:, 0]]).reshape(-1, 4, 2)
    angle = np.arctan2(v[..., 1], v[..., 0])
    v = v[np.arange(len(v))[:, None], np.argsort(angle, axis=1)]  # counter-clockwise
    length = np.linalg.norm(v, axis=2)
    ok = np.ones(len(centres), dtype=bool)
    for a, b in ((0, 2), (1, 3)):  # opposite neighbours: collinear through the centre, on either side
        cross = v[:, a, 0] * v[:, b, 1] - v[:, a, 1] * v[:, b, 0]
        dot = np.einsum("ij,ij->i", v[:, a], v[:, b])
        ok &= (np.abs(cross) <= CROSSED_TOLERANCE * length[:, a] * length[:, b]) & (dot < 0)
    result = np.zeros(n, dtype=bool)
    result[centres[ok]] = True
    return result


def locking_elements(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Elements that lock under plastic incompressibility (boolean per element): in
    2D the triangles with no criss-cross centre among their vertices, in 3D every
    tetrahedron (P1 tetrahedra lock on practically any mesh)."""
    if points.shape[1] == 3:
        return np.ones(cells.shape[0], dtype=bool)
    return ~np.any(crossed_centres(points, cells)[cells], axis=1)


def check_perfect_plasticity(disc) -> None:
    """Refuse ``hardening = 0`` on a mesh whose P1 elements lock.

    With perfect plasticity the plastic flow is incompressible. P1 triangles meet that
    constraint only on crossed meshes (four triangles per quadrilateral meeting at the
    intersection of its diagonals); two triangles per square and unstructured
    triangulations lock, and P1 tetrahedra lock on practically any mesh. On a locking
    mesh the discrete limit load lies far above the continuum's (measured: a flat punch
    solved at 3 x Prandtl's load in 2D; a 3D block "converged" to a U of metres on a
    block of millimetres), so the answer is no reference. ``disc`` is a
    :class:`Discretization` or a :class:`Problem` (anything with ``material`` and
    ``mesh``). Meant for the solve path only: the limit-load and bound programs do not
    use these elements for the velocity/stress fields that would lock.
    """
    if disc.material.hardening > 0:
        return
    mesh = disc.mesh
    bad = locking_elements(mesh.points, mesh.cells)
    if not np.any(bad):
        return
    if mesh.dim == 3:
        why = "P1 tetrahedra lock under plastically incompressible flow on practically any mesh"
        instead = "use hardening > 0, or `elastoplast limit` for the limit load"
    else:
        why = (f"{int(bad.sum())} of {bad.size} triangles are not in a crossed quadrilateral (four triangles meeting "
               "at the intersection of its diagonals), and such P1 triangles lock under plastically incompressible "
               "flow")
        instead = ("use hardening > 0, or a crossed mesh (pattern = \"crossed\"), or `elastoplast limit` for the "
                   "limit load")
    raise InputError("material.hardening",
                     f"hardening = 0 (perfect plasticity) on this mesh gives no reference answer: {why}, so the "
                     f"discrete limit load lies far above the true one; {instead}")
