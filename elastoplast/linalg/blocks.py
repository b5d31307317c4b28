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
    """Rigid-body motions of the nodes ``(n_dofs, 3 or 6)``: the near-null space of
    every stiffness-type matrix here (the clamped body has none exactly, but
    they are the smooth, low-energy modes multigrid must coarsen well).
    Rotations are scaled to the size of the translations."""
    modes = rigid_motions(lay.points)
    return modes / np.linalg.norm(modes, axis=0)
