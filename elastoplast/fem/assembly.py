"""Element geometry of P1 simplices and the one assembly of ``sum_T |T| B_T^T D_T B_T``.

Every stiffness-type matrix (the elastic stiffness ``D = C``, Newton's tangent
``D_T = C_ep,T``, Uzawa's metric ``D = I``) is assembled here, on one
:class:`Layout` per discretisation: the pattern of ``d x d`` blocks between
nodes that share an element, over every dof, and the block ``slots`` where each
element's vertex pairs add. Values live on the blocks themselves (BSR, what
multigrid takes) or on a :class:`ScalarView` of them: the CSR pattern of some
dofs (the free ones), whole or its upper triangle (what the direct
factorisations take), whose values are block values picked by ``take``, or,
for a matrix refilled at every step (Newton's), written directly through
element slots derived from the blocks'. :func:`fill` adds element matrices
``(n, m, m)`` into either; :func:`assemble` builds the element matrices from
the shape gradients in chunks and fills them, so its memory is the pattern,
the gradients and the slots, never a global copy of the element matrices.

Local dofs of an element are numbered ``a * d + component`` (vertex ``a``),
global ones ``node * d + component``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from math import factorial

import numpy as np
import scipy.sparse as sp

from elastoplast.errors import InputError
from elastoplast.mesh.base import Mesh

INV_SQRT2 = 1.0 / np.sqrt(2.0)

# Mandel rows of eps = sym(grad u) as (component, derivative, weight) triples.
STRAIN_ROWS = {
    2: [[(0, 0, 1.0)], [(1, 1, 1.0)], [], [(0, 1, INV_SQRT2), (1, 0, INV_SQRT2)]],
    3: [
        [(0, 0, 1.0)],
        [(1, 1, 1.0)],
        [(2, 2, 1.0)],
        [(1, 2, INV_SQRT2), (2, 1, INV_SQRT2)],
        [(0, 2, INV_SQRT2), (2, 0, INV_SQRT2)],
        [(0, 1, INV_SQRT2), (1, 0, INV_SQRT2)],
    ],
}

#: elements per chunk of the assembly: bounds its temporaries (a chunk of 3D
#: element matrices is 2^14 * 144 doubles = 19 MB, below glibc's largest mmap
#: threshold, so chunks reuse their memory instead of faulting in fresh pages)
CHUNK = 1 << 14


# ----------------------------------------------------------------------------
# element geometry
# ----------------------------------------------------------------------------


def element_geometry(mesh: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """``(volumes, gradients)``; refuses degenerate and inverted simplices."""
    return simplex_geometry(mesh.points, mesh.cells)


def simplex_geometry(points: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`element_geometry` of the simplices ``cells`` (node indices into ``points``)."""
    d = points.shape[1]
    n_elements = cells.shape[0]
    X = points[cells]
    J = element_jacobians(points, cells)
    det = np.linalg.det(J)
    edges = np.concatenate([X[:, i] - X[:, j] for i in range(d + 1) for j in range(i)], axis=0)
    h = np.linalg.norm(edges.reshape(-1, n_elements, d), axis=2).max(axis=0)
    degenerate = np.abs(det) <= 1e-10 * h**d
    if np.any(degenerate):
        bad = np.flatnonzero(degenerate)
        raise InputError(
            "mesh", f"{bad.size} degenerate element(s) (zero volume), first: element {bad[0]} with nodes {cells[bad[0]].tolist()}"
        )
    sign = np.sign(det)
    majority = 1.0 if np.sum(sign > 0) >= np.sum(sign < 0) else -1.0
    if np.any(sign != majority):
        bad = np.flatnonzero(sign != majority)
        raise InputError(
            "mesh", f"{bad.size} inverted element(s) (orientation opposite to the rest), first: element {bad[0]}"
        )
    return np.abs(det) / factorial(d), shape_gradients(J)


def element_jacobians(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """``J[e] = [x_1 - x_0, ..., x_d - x_0]`` (columns) of each simplex."""
    X = points[cells]
    return np.swapaxes(X[:, 1:] - X[:, :1], 1, 2)


def shape_gradients(J: np.ndarray) -> np.ndarray:
    """Gradients ``(n_el, d+1, d)`` of the P1 shape functions from the Jacobians:
    the rows of ``J^{-1}`` for phi_1..phi_d and minus their sum for phi_0."""
    Jinv = np.linalg.inv(J)
    return np.concatenate([-Jinv.sum(axis=1, keepdims=True), Jinv], axis=1)


def rigid_motions(points: np.ndarray, axisymmetric: bool = False) -> np.ndarray:
    """Basis ``(n_nodes * d, r)`` of infinitesimal rigid motions at the nodes. In an
    axisymmetric model only the axial translation is one (a radial translation or an
    in-plane rotation strains the hoops)."""
    n, d = points.shape
    if axisymmetric:
        t = np.zeros((n, d))
        t[:, 1] = 1.0
        return t.reshape(-1, 1)
    x = points - points.mean(axis=0)
    modes = []
    for a in range(d):
        t = np.zeros((n, d))
        t[:, a] = 1.0
        modes.append(t)
    for a, b in ([(0, 1)] if d == 2 else [(0, 1), (1, 2), (0, 2)]):
        r = np.zeros((n, d))
        r[:, a], r[:, b] = -x[:, b], x[:, a]
        modes.append(r)
    return np.stack([m.ravel() for m in modes], axis=1)


#: the Mandel row of the hoop strain in an axisymmetric model (the slot that is zero in plane strain)
HOOP_ROW = 2


def strain_matrices(grads: np.ndarray, hoop: np.ndarray | None = None) -> np.ndarray:
    """Element strain matrices ``B_T (n, k, (d+1) d)`` (Mandel rows, local dofs
    ``a * d + component``) from the shape gradients ``(n, d+1, d)``.

    ``hoop (n,)``, in an axisymmetric model, is ``1 / r_T`` (the centroid's radius):
    the hoop strain is then the mean nodal radial displacement over ``r_T``
    (docs/axisymmetry.md); None in plane strain and 3D."""
    n, m, d = grads.shape
    rows = STRAIN_ROWS[d]
    B = np.zeros((n, len(rows), m, d))
    for c, terms in enumerate(rows):
        for comp, der, w in terms:
            B[:, c, :, comp] += w * grads[:, :, der]
    if hoop is not None:
        B[:, HOOP_ROW, :, 0] = hoop[:, None] / m
    return B.reshape(n, len(rows), m * d)


def element_matrices(grads: np.ndarray, volumes: np.ndarray, D: np.ndarray,
                     hoop: np.ndarray | None = None) -> np.ndarray:
    """``|T| B_T^T D_T B_T`` ``(n, m, m)`` for one ``D (k, k)`` shared by the
    ``n`` elements or one each, ``D (n, k, k)`` (``|T|``: the element's weight,
    ``hoop``: see :func:`strain_matrices`)."""
    B = strain_matrices(grads, hoop)
    if D.ndim == 2:
        DB = np.matmul(D, B) * volumes[:, None, None]
    else:
        DB = np.matmul(D * volumes[:, None, None], B)
    return np.matmul(np.swapaxes(B, 1, 2), DB)


def index_dtype(n: int) -> type:
    """The smallest integer type that numbers ``n`` things."""
    return np.int32 if n < np.iinfo(np.int32).max else np.int64


# ----------------------------------------------------------------------------
# the pattern and its fill
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Layout:
    """Block sparsity of the stiffness over the nodes and where elements add into it.

    Block row ``i`` holds the blocks ``indices[indptr[i]:indptr[i+1]]`` (the
    nodes sharing an element with node i, sorted); ``brow`` is each block's
    row, ``diag`` each node's diagonal block, ``slots (n_el, (d+1)^2)`` the block
    of the local pair ``(a, b)`` of each element. ``grads (n_el, d+1, d)`` are
    the shape-function gradients, ``volumes`` the element weights and ``hoop``
    the reciprocal centroid radii of an axisymmetric model (None otherwise) the
    element matrices are built from (in the units of their discretisation).
    Values on it are ``(n_blocks, d, d)`` blocks (BSR).
    """

    dim: int
    n_nodes: int
    indptr: np.ndarray
    indices: np.ndarray
    brow: np.ndarray
    diag: np.ndarray
    slots: np.ndarray
    grads: np.ndarray
    volumes: np.ndarray
    hoop: np.ndarray | None

    #: element entries read by :func:`fill` (None: all of them)
    entries = None

    @property
    def n_blocks(self) -> int:
        return self.indices.size

    @property
    def n_dofs(self) -> int:
        return self.n_nodes * self.dim

    @property
    def size(self) -> int:
        return self.n_blocks * self.dim**2

    @property
    def shape(self) -> tuple[int, int, int]:
        return self.n_blocks, self.dim, self.dim

    def positions(self, elements: np.ndarray) -> np.ndarray:
        """Positions ``(n, m*m)`` of the entries of ``elements``' element matrices
        in the flattened block values (entry ``(a d + i, b d + j)`` in block
        ``slots[e, a (d+1) + b]`` at ``(i, j)``)."""
        d, v = self.dim, self.dim + 1
        s = self.slots[elements].astype(np.int64)
        s *= d * d
        out = np.empty((s.shape[0], v, d, v, d), dtype=np.int64)
        np.add(s.reshape(-1, v, 1, v, 1), (np.arange(d)[:, None] * d + np.arange(d)).reshape(d, 1, d), out=out)
        return out.reshape(s.shape[0], -1)


def element_layout(mesh: Mesh, grads: np.ndarray, volumes: np.ndarray, hoop: np.ndarray | None = None) -> Layout:
    """The block pattern of ``mesh`` and the slots of its elements' vertex pairs."""
    n, d = mesh.n_nodes, mesh.dim
    cells = mesh.cells
    keys = (cells[:, :, None].astype(np.int64) * n + cells[:, None, :]).reshape(-1)
    uniq, inverse = np.unique(keys, return_inverse=True)
    del keys
    it = index_dtype(max(uniq.size, n))
    brow = (uniq // n).astype(it)
    indices = (uniq % n).astype(it)
    del uniq
    indptr = np.zeros(n + 1, dtype=it)
    np.cumsum(np.bincount(brow, minlength=n), out=indptr[1:])
    diag = np.flatnonzero(brow == indices).astype(it)  # every node is its own neighbour: one per row
    return Layout(dim=d, n_nodes=n, indptr=indptr, indices=indices, brow=brow, diag=diag,
                  slots=inverse.reshape(mesh.n_elements, (d + 1) ** 2).astype(it), grads=grads,
                  volumes=np.asarray(volumes, dtype=float), hoop=hoop)


@dataclass(frozen=True)
class ScalarView:
    """The matrices of a :class:`Layout` on some dofs as CSR (``n`` rows, whole
    or the upper triangle): row ``r`` holds the columns ``indices[indptr[r]:indptr[r+1]]``,
    whose values are the block values at ``take`` (flattened ``(n_blocks, d, d)``).

    With ``slots (n_el, len(entries))`` :func:`fill` also writes the view's
    values directly: they are the positions of each element's ``entries``
    (flat local indices ``row * m + col``: all of them, or those with
    ``row <= col`` for the upper triangle) in the values, ``size`` where the
    entry is left out (at a dof not in the view).
    """

    n: int
    indptr: np.ndarray
    indices: np.ndarray
    take: np.ndarray | None = None
    slots: np.ndarray | None = None
    entries: np.ndarray | None = None

    @property
    def size(self) -> int:
        return self.indices.size

    @property
    def shape(self) -> tuple[int]:
        return (self.size,)

    def positions(self, elements: np.ndarray) -> np.ndarray:
        return self.slots[elements]

    def from_blocks(self, blocks: np.ndarray) -> np.ndarray:
        """The view's values of the layout's block values ``(n_blocks, d, d)``."""
        return blocks.reshape(-1)[self.take]

    def csr(self, values: np.ndarray) -> sp.csr_matrix:
        """The CSR matrix of the view's ``values``."""
        return sp.csr_matrix((values, self.indices, self.indptr), shape=(self.n, self.n))


def scalar_view(lay: Layout, dofs: np.ndarray, upper: bool = False, slots: bool = False) -> ScalarView:
    """The CSR pattern of ``lay`` on ``dofs`` (increasing; numbered in that
    order), whole or its ``upper`` triangle, with the element ``slots`` into it
    when asked.

    Row ``r = I d + i`` of the whole matrix runs over the blocks of block row
    ``I`` and their columns ``j``, so its entries are written in CSR order
    directly and those of kept dofs picked: no sort. Element matrices are
    symmetric, so for the upper triangle each element gives its own upper
    entries, at the global entry or its transpose.
    """
    d, dd, m = lay.dim, lay.dim**2, (lay.dim + 1) * lay.dim
    position = np.full(lay.n_dofs, -1, dtype=np.int64)
    position[dofs] = np.arange(dofs.size)
    node, i = np.divmod(dofs, d)
    first = lay.indptr[node].astype(np.int64)  # first block of each row
    length = (lay.indptr[node + 1] - first) * d
    row = np.repeat(np.arange(dofs.size), length)  # the row of each entry of the kept rows
    offset = np.arange(row.size) - np.repeat(np.cumsum(length) - length, length)
    block, j = np.divmod(offset, d)
    block += first[row]
    col = position[lay.indices[block] * d + j]
    kept = col >= row if upper else col >= 0
    take = block[kept] * dd + i[row[kept]] * d + j[kept]  # the block value of each entry
    it = index_dtype(max(take.size, dofs.size) + 1)
    indptr = np.zeros(dofs.size + 1, dtype=it)
    np.cumsum(np.bincount(row[kept], minlength=dofs.size), out=indptr[1:])
    view = ScalarView(n=dofs.size, indptr=indptr, indices=col[kept].astype(it), take=take)
    if not slots:
        return view
    where = np.full(lay.size, take.size, dtype=np.int64)  # the view's value of each block value
    where[take] = np.arange(take.size)
    if upper:  # a lower entry goes where its transpose is
        lower = (col >= 0) & (col < row)
        b, il, jl = block[lower], i[row[lower]], j[lower]
        keys = lay.brow.astype(np.int64) * lay.n_nodes + lay.indices
        transposed = np.searchsorted(keys, lay.indices[b].astype(np.int64) * lay.n_nodes + lay.brow[b])
        where[b * dd + il * d + jl] = where[transposed * dd + jl * d + il]
    del row, offset, block, j, col, kept
    entries = np.flatnonzero(np.arange(m)[:, None] <= np.arange(m)) if upper else None
    n_el = lay.slots.shape[0]
    element_slots = np.empty((n_el, m * m if entries is None else entries.size), dtype=np.int64)
    for s in range(0, n_el, CHUNK):
        pos = lay.positions(np.arange(s, min(s + CHUNK, n_el)))
        element_slots[s:s + CHUNK] = where[pos if entries is None else pos[:, entries]]
    return replace(view, slots=element_slots, entries=entries)


def fill(target: Layout | ScalarView, Ke: np.ndarray, elements: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Adds the element matrices ``Ke (n, m, m)`` of ``elements`` into ``out``
    (C-contiguous; zeros when None): block values ``(n_blocks, d, d)`` of a
    :class:`Layout` or the values of a :class:`ScalarView` with slots; returns ``out``.

    ``np.add.at`` adds in place (on 192k tetrahedra it took 0.24 s for the
    blocks against 0.43 s for ``np.bincount``'s fresh array of every value and
    0.62 s for one bincount per block entry).
    """
    w = Ke.reshape(Ke.shape[0], -1)
    if target.entries is not None:
        w = w[:, target.entries]
    out = np.zeros(target.shape) if out is None else out
    if not out.flags.c_contiguous:
        raise ValueError("fill adds into a C-contiguous array")
    if isinstance(target, ScalarView):  # one more value for the entries left out
        extra = np.zeros(target.size + 1)
        np.add.at(extra, target.positions(elements).ravel(), w.ravel())
        out += extra[:-1]
    else:
        np.add.at(out.reshape(-1), target.positions(elements).ravel(), w.ravel())
    return out


def assemble(lay: Layout, D: np.ndarray, elements: np.ndarray | None = None, out: np.ndarray | None = None,
             subtract: np.ndarray | None = None, view: ScalarView | None = None) -> np.ndarray:
    """Values of ``sum_T |T| B_T^T (D_T - subtract) B_T`` on ``lay``'s blocks, or
    on ``view`` (with slots) when given.

    ``D`` is one ``(k, k)`` matrix for every element or one per element of
    ``elements`` (``(len(elements), k, k)``; all elements when None); the sum
    runs over ``elements`` and is added to ``out`` when given (a correction
    of an assembled matrix, e.g. the plastic elements' tangent minus C).
    """
    target = lay if view is None else view
    if elements is None:
        elements = np.arange(lay.volumes.size)
    out = np.zeros(target.shape) if out is None else out
    for s in range(0, elements.size, CHUNK):
        e = elements[s:s + CHUNK]
        De = D if D.ndim == 2 else D[s:s + CHUNK]
        if subtract is not None:
            De = De - subtract
        hoop = None if lay.hoop is None else lay.hoop[e]
        fill(target, element_matrices(lay.grads[e], lay.volumes[e], De, hoop), e, out)
    return out
