"""Node-block sparse matrices: the layout of the stiffness-type matrices of the iterative
path, their Dirichlet rows, block transposes and rows, and the near-null space of
multigrid (:mod:`elastoplast.linalg.amg` builds its hierarchies on them).

The matrices ``sum_T |T| B_T^T D_T B_T`` are stored as BSR with one ``d x d`` block per
pair of neighbouring nodes, over every dof (fixed ones included, as identity-like rows):
the discretisation's :class:`~elastoplast.fem.assembly.Layout`, assembled element by
element in chunks by :func:`~elastoplast.fem.assembly.assemble` without a global copy of
per-element matrices."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np
import scipy.sparse as sp

from elastoplast.fem.assembly import Layout, rigid_motions
from elastoplast.fem.discretize import Discretization


@dataclass(frozen=True)
class BlockLayout(Layout):
    """The :class:`~elastoplast.fem.assembly.Layout` of a discretisation with what
    the iterative path adds: ``free`` marks the free dofs (``node * d +
    component``) and ``points`` are the nodes in the layout's length unit (for
    the near-null space)."""

    free: np.ndarray
    points: np.ndarray = field(repr=False)

    def embed(self, x_free: np.ndarray, free_index: np.ndarray) -> np.ndarray:
        """A vector on the free dofs as a vector on every dof (zeros at fixed ones)."""
        out = np.zeros(self.n_dofs)
        out[free_index] = x_free
        return out


def block_layout(disc: Discretization, length: float = 1.0) -> BlockLayout:
    """The block pattern of ``disc``'s mesh (``disc.layout``); nodes in units of ``length``.

    ``length`` is the unit of a nondimensionalised discretisation
    (:class:`~elastoplast.fem.discretize.Units`): ``disc.B`` and the gradients
    of ``nondimensionalize(disc)`` are the original ones times ``length``.
    """
    lay = disc.layout
    free = np.zeros(lay.n_dofs, dtype=bool)
    free[disc.free] = True
    return BlockLayout(**{f.name: getattr(lay, f.name) for f in fields(Layout)}, free=free,
                       points=disc.mesh.points / length)


def constrain(lay: BlockLayout, data: np.ndarray, fixed: np.ndarray,
              transpose: np.ndarray | None = None) -> np.ndarray:
    """Rows and columns of the ``fixed`` dofs (bool, every dof) zeroed, their diagonal kept.

    With ``transpose`` (:func:`block_transpose` of the layout) only the blocks in the
    rows and columns of the fixed nodes are touched: one copy of ``data`` instead of
    the products of every block by the rows' and the columns' masks and their
    temporaries (measured at 375k tetrahedra: 0.14 -> 0.03 s a face; the same values,
    up to the sign of a zero)."""
    if transpose is None:
        keep = (~fixed).reshape(lay.n_nodes, lay.dim).astype(float)
        out = data * keep[lay.brow][:, :, None]
        out *= keep[lay.indices][:, None, :]
    else:
        dofs = np.flatnonzero(fixed)
        nodes, comps = np.divmod(dofs, lay.dim)
        starts, counts = lay.indptr[nodes], lay.indptr[nodes + 1] - lay.indptr[nodes]
        # the block positions of each fixed dof's row, and the component, one per block
        pos = np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
        comp = np.repeat(comps, counts)
        out = data.copy()
        out[pos, comp, :] = 0.0
        out[transpose[pos], :, comp] = 0.0  # the column of that dof: the transposed blocks
    nodes, comps = np.nonzero(fixed.reshape(lay.n_nodes, lay.dim))
    out[lay.diag[nodes], comps, comps] = data[lay.diag[nodes], comps, comps]
    return out


def row_blocks(lay: BlockLayout, nodes: np.ndarray) -> np.ndarray:
    """The block positions of the rows of ``nodes`` (in the layout's order)."""
    starts, counts = lay.indptr[nodes], lay.indptr[nodes + 1] - lay.indptr[nodes]
    return np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())


def constrain_again(lay: BlockLayout, data: np.ndarray, out: np.ndarray, was: np.ndarray, fixed: np.ndarray,
                    transpose: np.ndarray) -> np.ndarray:
    """``constrain(lay, data, fixed, transpose)`` written into ``out``, which holds
    ``constrain(lay, data, was, transpose)``: the blocks in the rows and columns of the
    nodes with a dof whose state changed are read from ``data`` again, then every fixed
    dof's row and column is zeroed and its diagonal kept, as :func:`constrain` does.
    A block of two unchanged nodes has the same fixed rows and columns in both faces,
    so it is already right: the same values as :func:`constrain` without its copy of
    every block (measured at 375k tetrahedra: 2.1 s of copies in Uzawa's 33 new faces)."""
    nodes = np.unique(np.flatnonzero(was != fixed) // lay.dim)
    pos = row_blocks(lay, nodes)
    out[pos] = data[pos]
    out[transpose[pos]] = data[transpose[pos]]
    dofs = np.flatnonzero(fixed)
    nodes, comps = np.divmod(dofs, lay.dim)
    counts = lay.indptr[nodes + 1] - lay.indptr[nodes]
    pos = row_blocks(lay, nodes)
    comp = np.repeat(comps, counts)
    out[pos, comp, :] = 0.0
    out[transpose[pos], :, comp] = 0.0
    out[lay.diag[nodes], comps, comps] = data[lay.diag[nodes], comps, comps]
    return out


def block_transpose(lay: BlockLayout) -> np.ndarray:
    """For each block position ``p`` of the (structurally symmetric) pattern, the
    position of its transposed block: block ``(i, j)`` at ``p``, ``(j, i)`` at ``transpose[p]``."""
    n = np.int64(lay.n_nodes)
    rows = np.repeat(np.arange(lay.n_nodes, dtype=np.int64), np.diff(lay.indptr))
    key = rows * n + lay.indices
    order = np.argsort(key, kind="stable")
    found = order[np.searchsorted(key[order], lay.indices.astype(np.int64) * n + rows)]
    if not np.array_equal(key[found], lay.indices.astype(np.int64) * n + rows):
        raise ValueError("the block pattern is not structurally symmetric")
    return found


def bsr(lay: BlockLayout, data: np.ndarray) -> sp.bsr_matrix:
    """The BSR matrix of block values ``data`` on the layout's pattern."""
    n = lay.n_dofs
    return sp.bsr_matrix((data, lay.indices, lay.indptr), shape=(n, n))


def block_rows(lay: BlockLayout, data: np.ndarray, dofs: np.ndarray) -> sp.csr_matrix:
    """Rows ``dofs`` (every-dof numbering) of the BSR matrix of block values ``data``, as
    CSR, read from the blocks of their nodes: ``bsr(lay, data).tocsr()[dofs]`` without
    the whole matrix converted (1.1 s at 1.03M tetrahedra, for a few hundred rows)."""
    d = lay.dim
    nodes, comps = np.divmod(np.asarray(dofs), d)
    starts, counts = lay.indptr[nodes], lay.indptr[nodes + 1] - lay.indptr[nodes]
    pos = np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
    comp = np.repeat(comps, counts)
    values = data[pos, comp, :].reshape(-1)  # (blocks, d): the row's d entries in each block
    columns = (lay.indices[pos][:, None] * d + np.arange(d)).reshape(-1)
    indptr = np.zeros(len(nodes) + 1, dtype=np.int64)
    np.cumsum(counts * d, out=indptr[1:])
    return sp.csr_matrix((values, columns, indptr), shape=(len(nodes), lay.n_dofs))


def near_null_space(lay: BlockLayout) -> np.ndarray:
    """The near-null space of multigrid ``(n_dofs, 3 or 6)``: the rigid-body motions of the
    nodes, in an axisymmetric model those of the meridian plane (two translations and the
    in-plane rotation). The clamped body has no null space, but these are the smooth,
    low-energy modes each aggregate must represent. In axisymmetry only the axial
    translation is a rigid motion of the whole body; the radial translation and the
    rotation strain the hoops by u_r / r only, a term of lower order on an aggregate of
    size h at radius r >> h, so they are low-energy modes of every aggregate off the axis.
    With the axial translation alone (one vector per node block of two) the coarse levels
    hold no radial displacement at all, pyamg warns "less target vectors than blocksize",
    and CG stalls: measured on ``problems/sphere_axisymmetric.toml`` (elastic stiffness,
    CG to 1e-10), 1000 iterations at 10,368 triangles and no convergence in 3000 at
    100,352, against 48 and 54 with the three modes (75 and 86 with the two translations).
    Rotations are scaled to the size of the translations."""
    modes = rigid_motions(lay.points)
    return modes / np.linalg.norm(modes, axis=0)


def add_in_place(A: sp.bsr_matrix, delta: sp.spmatrix) -> bool:
    """``A += delta`` in ``A``'s own block values when every block of ``delta`` is one of
    ``A``'s (a change of a coarse operator ``R (A - A_old) P`` lies in the pattern of
    ``R A P``); returns False, ``A`` untouched, when one is not. Each value is the sum
    ``a + d`` of scipy's ``A + delta`` (blocks of ``A`` that ``delta`` lacks keep their
    values); scipy's sum builds a new matrix over every block instead (in another order
    of the blocks within a row, so a V-cycle differs from its in the last bits), and
    drops blocks that come out all zero, which stay here as explicit zeros. pyamg's
    caches of the old values on ``A`` (:data:`PYAMG_CACHES`) are dropped. Measured at
    375k tetrahedra (Uzawa, 33 new faces): 3.7 s of the coarse sums of a 67 s run."""
    if not sp.issparse(delta) or delta.nnz == 0:
        return sp.issparse(delta)
    delta = delta.tobsr(blocksize=A.blocksize, copy=True)  # the caller's stays as it is (its order of blocks too)
    delta.sum_duplicates()
    n_cols = np.int64(A.shape[1] // A.blocksize[1])
    key_A = np.repeat(np.arange(len(A.indptr) - 1, dtype=np.int64), np.diff(A.indptr)) * n_cols + A.indices
    key_d = np.repeat(np.arange(len(delta.indptr) - 1, dtype=np.int64), np.diff(delta.indptr)) * n_cols \
        + delta.indices
    order = None if A.has_sorted_indices else np.argsort(key_A, kind="stable")  # A's block order stays
    sorted_keys = key_A if order is None else key_A[order]
    pos = np.searchsorted(sorted_keys, key_d)
    if np.any(pos >= key_A.size) or not np.array_equal(sorted_keys[np.minimum(pos, key_A.size - 1)], key_d):
        return False
    A.data[pos if order is None else order[pos]] += delta.data
    for name in PYAMG_CACHES:  # what pyamg keeps on a matrix of the values it had (the smoother's D^-1)
        if name in A.__dict__:
            delattr(A, name)
    return True


#: the attributes pyamg stores on a matrix for later calls (``get_block_diag``'s block
#: diagonal and its inverse, the spectral radius): stale once its values change in place
PYAMG_CACHES = ("block_D_inv", "block_D", "rho")


def changed_blocks(old: sp.bsr_matrix, new: sp.bsr_matrix) -> sp.bsr_matrix:
    """``new - old`` for two BSR matrices of one pattern, with only the blocks that differ stored."""
    # one byte per entry compared, the differences of the few changed blocks only: 0.055 s
    # at 1.03M tetrahedra against 0.18-0.54 s for the whole float difference
    differs = np.flatnonzero(np.not_equal(new.data, old.data).reshape(-1))
    keep = np.unique(differs // old.data[0].size)
    rows = np.searchsorted(old.indptr, keep, side="right") - 1
    indptr = np.zeros(len(old.indptr), dtype=old.indptr.dtype)
    np.cumsum(np.bincount(rows, minlength=len(indptr) - 1), out=indptr[1:])
    return sp.bsr_matrix((new.data[keep] - old.data[keep], old.indices[keep], indptr), shape=old.shape)
