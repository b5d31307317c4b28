"""The rows of the stress form (S) of (2.1), built once in a neutral sign convention (docs/methods.md).

(S) in energy-normalised unknowns (``tau_hat_T = w_T tau_T``, ``xi_hat_T = w_T xi_T``,
:func:`element_weights`) has three kinds of constraints, each a group of affine rows
``g(x) = G x + h`` that must lie in a cone:

* equilibrium, ``sum_T w_T B_T^T tau_hat_T - N^T lam = 0`` (:func:`equilibrium_rows`),
  and the force balance, ``sum lam - F = 0`` (:func:`force_row`): the zero cone;
* the contact pressures, ``lam >= 0`` (:func:`contact_sign_rows`): the nonnegative cone;
* the yield condition, ``(w_T sigma_y + xi_hat_T, sqrt(3/2) Q^T tau_hat_T)`` in a
  second-order cone of size k per element (:func:`yield_rows`).

Each consumer turns the groups into its own convention with a thin adapter: Clarabel's
``s = b - A x`` (:func:`~elastoplast.solvers.backends.clarabel_rows`, used by the
``conic`` method and by the lower bound's program, whose yield cones are the same rows
at the element vertices) and CBF's ``A x + b`` (:mod:`elastoplast.io.export`, which
takes G and h as they are). The builders take plain arrays where a caller may need
other elements than a discretisation's (the vertices of the equilibrium element).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import SQRT_3_2

#: the cones of the row groups (Clarabel's ZeroConeT, NonnegativeConeT, SecondOrderConeT;
#: CBF's L=, L+, Q)
CONES = ("zero", "nonnegative", "second_order")


@dataclass(frozen=True)
class AffineRows:
    """``g(x) = G x + h`` on ``n_rows`` rows, ``G`` as COO triplets (``row``, ``col``,
    ``val``; columns are global, rows local to the group) and ``h`` as its nonzero
    entries (``h_rows``, ``h_vals``); ``g`` lies in the ``cone``, of size ``cone_size``
    each (the group is ``n_rows / cone_size`` cones, one for the zero and nonnegative
    cones)."""

    n_rows: int
    row: np.ndarray
    col: np.ndarray
    val: np.ndarray
    h_rows: np.ndarray
    h_vals: np.ndarray
    cone: str
    cone_size: int

    def h(self) -> np.ndarray:
        """``h`` as a dense vector."""
        out = np.zeros(self.n_rows)
        out[self.h_rows] = self.h_vals
        return out


def volume_weights(volumes: np.ndarray) -> np.ndarray:
    """``w = sqrt(|T| / mean |T|)``: the weights of the energy-normalised unknowns, which
    keep them the size of the stresses."""
    return np.sqrt(volumes / volumes.mean())


def element_weights(disc: Discretization) -> np.ndarray:
    """``w_T`` of the energy-normalised unknowns ``tau_hat_T = w_T tau_T``: ``sqrt|T|``
    relative to the mean element (:func:`volume_weights` of the element volumes)."""
    return volume_weights(disc.volumes)


def deviatoric_basis(k: int) -> np.ndarray:
    """Orthonormal basis ``Q (k, k-1)`` of trace-free Mandel vectors: ``|dev t| = |Q^T t|``."""
    Q = np.zeros((k, k - 1))
    Q[:3, 0] = np.array([1.0, -1.0, 0.0]) / np.sqrt(2.0)
    Q[:3, 1] = np.array([1.0, 1.0, -2.0]) / np.sqrt(6.0)
    Q[3:, 2:] = np.eye(k - 3)
    return Q


def equilibrium_rows(disc: Discretization, tau_col: int, lam_col: int) -> AffineRows:
    """``sum_T w_T B_T^T tau_hat_T - N^T lam`` (one row per free dof), in the zero cone."""
    BtW = (disc.B.T @ sp.diags(np.repeat(element_weights(disc), disc.k))).tocoo()
    Nt = disc.N.T.tocoo()
    empty = np.zeros(0, dtype=np.int64)
    return AffineRows(disc.n_free, np.concatenate([BtW.row, Nt.row]), np.concatenate([tau_col + BtW.col, lam_col + Nt.col]),
                      np.concatenate([BtW.data, -Nt.data]), empty, np.zeros(0), "zero", disc.n_free)


def force_row(disc: Discretization, lam_col: int) -> AffineRows:
    """``sum lam - F``, in the zero cone."""
    nc = disc.n_contact
    return AffineRows(1, np.zeros(nc, dtype=np.int64), lam_col + np.arange(nc), np.ones(nc),
                      np.zeros(1, dtype=np.int64), np.array([-disc.force]), "zero", 1)


def contact_sign_rows(n_contact: int, lam_col: int) -> AffineRows:
    """``lam`` (the ``n_contact`` columns from ``lam_col``) in the nonnegative cone."""
    return AffineRows(n_contact, np.arange(n_contact), lam_col + np.arange(n_contact), np.ones(n_contact),
                      np.zeros(0, dtype=np.int64), np.zeros(0), "nonnegative", n_contact)


def yield_rows(k: int, weights: np.ndarray, yield_stress: float, tau_col: int, xi_col: int | None) -> AffineRows:
    """``(w_T sigma_y + xi_hat_T, sqrt(3/2) Q^T tau_hat_T)`` in a second-order cone of size k,
    one per entry of ``weights`` (the elements, or the element vertices of the lower bound's
    program); ``tau_hat`` the ``k`` columns per cone from ``tau_col``, ``xi_hat`` one column per
    cone from ``xi_col`` (None: no hardening variable)."""
    n = weights.size
    dev = sp.kron(sp.eye(n), sp.csr_matrix(SQRT_3_2 * deviatoric_basis(k).T)).tocoo()  # rows T (k-1) + i
    r, c, v = [(dev.row // (k - 1)) * k + 1 + dev.row % (k - 1)], [tau_col + dev.col], [dev.data]
    if xi_col is not None:
        r.append(np.arange(n) * k)
        c.append(xi_col + np.arange(n))
        v.append(np.ones(n))
    return AffineRows(n * k, np.concatenate(r), np.concatenate(c), np.concatenate(v), np.arange(n) * k,
                      weights * yield_stress, "second_order", k)
