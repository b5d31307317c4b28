"""Solver-independent KKT certificate of (2.1) (docs/certificate.md).

:func:`certify` takes any candidate ``(sigma, xi, u, U)`` (and optionally the
contact forces the solver claims) and measures how far it is from the discrete
solution. It uses nothing but the discretisation and the return mapping, so the
same check applies to every solver.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass

import numpy as np

from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import return_mapping
from elastoplast.options import check_array
from elastoplast.errors import short_repr


#: relative round-off of a computed nodal force: 64 machine epsilons of the sum of the
#: magnitudes of its terms (a sum of a few dozen products)
ROUND_OFF = 64 * np.finfo(float).eps


@dataclass(frozen=True)
class KKTResiduals:
    """Relative KKT residuals of a candidate, each with its scale.

    With ``r = sum_T |T| B_T^T sigma_T`` on the free dofs, ``lam`` the contact
    forces (given, or ``r`` at the vertical contact dofs), ``g = u_d + psi - U``
    the gaps and ``delta = max(|U|, max|u|)`` the displacement scale (on a step of a
    loading path also the largest displacement reached before it, ``state.displacement``):

    * ``constitutive``: ``||sigma_hat - R(eps(u))||_E / ||R(eps(u))||_E`` in the
      energy norm ``[.,.]`` (the xi part is dropped when H = 0);
    * ``constitutive_max``: the same element by element, without volume weights:
      ``max_T |sigma_hat_T - R_T|_e / max_T |R_T|_e`` with the pointwise norm
      ``|tau_hat|_e^2 = tau A tau + eta^2 / H``. The global norm dilutes an
      error confined to one element; this one does not;
    * ``equilibrium``: ``||r - N^T lam||_2 / ||s||_2`` over the free dofs, where
      ``s = |B|^T |sigma |T||`` sums, at each dof, the magnitudes of every
      single term (element and stress component) that enters ``r`` there;
    * ``force_balance``: ``|sum lam - F| / F``;
    * ``sign``: ``sum max(-lam, 0) / F``;
    * ``penetration``: ``max(-g, 0).max() / delta``;
    * ``complementarity``: ``sum |lam g| / (F delta)``, where a ``lam_i`` within
      the round-off of its computation (``|lam_i| <= ROUND_OFF * (s_i + p_i)``,
      ``s_i`` the equilibrium scale at that dof, ``p_i`` the rounding of ``u``
      propagated, :func:`propagated`) counts as zero: a round-off force times a
      wide gap (an obstacle far from a node) is no violation;
    * ``dirichlet``: ``max |u| over fixed dofs / delta``.
    """

    constitutive: float
    constitutive_max: float
    equilibrium: float
    force_balance: float
    sign: float
    penetration: float
    complementarity: float
    dirichlet: float

    @property
    def worst(self) -> float:
        """The largest residual; NaN if any residual is NaN (a NaN is never "small")."""
        values = list(self.as_dict().values())
        return math.nan if any(math.isnan(v) for v in values) else max(values)

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


def energy_density(disc: Discretization, sigma: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Pointwise ``sigma A sigma + xi^2 / H`` per element (xi dropped when H = 0)."""
    A = disc.material.compliance(disc.dim)
    val = np.einsum("ei,ij,ej->e", sigma, A, sigma)
    H = disc.material.hardening
    if H > 0:
        val = val + xi**2 / H
    return val


def energy_norm_sq(disc: Discretization, sigma: np.ndarray, xi: np.ndarray) -> float:
    """``[sigma_hat, sigma_hat] = sum_T |T| (sigma A sigma + xi^2 / H)``."""
    return float(disc.volumes @ energy_density(disc, sigma, xi))


def work_density(disc: Discretization, sigma: np.ndarray, dkappa: np.ndarray) -> np.ndarray:
    """The integrand of (D) per element at the return mapping's ``(sigma, dkappa)``:
    ``1/2 sigma A sigma + sigma_y kappa + 1/2 H kappa^2`` (``eps - p = A sigma``).

    On a step from a state (``disc.state``: ``sigma_n``, ``xi_n``) it is the
    step's incremental energy ``W_n``, ``1/2 sigma A sigma - 1/2 sigma_n A sigma_n
    + (sigma_y + xi_n) dkappa + 1/2 H dkappa^2`` (docs/evolution.md), which is
    Hencky's at ``sigma_n = 0, xi_n = 0``."""
    A = disc.material.compliance(disc.dim)
    m, state = disc.material, disc.state
    density = 0.5 * np.einsum("ei,ij,ej->e", sigma, A, sigma) + m.yield_stress * dkappa
    density += 0.5 * m.hardening * dkappa**2
    if state is not None:
        density += state.xi * dkappa - 0.5 * np.einsum("ei,ei->e", state.sigma, state.strain)
    return density


def gaps(disc: Discretization, u_free: np.ndarray, U: float) -> np.ndarray:
    """``g_i = u_d(x_i) + psi_i - U`` at the contact nodes."""
    return disc.N @ u_free + disc.psi - U


def contact_forces(disc: Discretization, sigma: np.ndarray) -> np.ndarray:
    """Contact forces implied by the stresses: ``r`` at the vertical contact dofs."""
    return disc.N @ disc.internal_force(sigma)


#: rows of B per chunk of :func:`abs_transpose_product` (bounds its temporaries to ~12 MB)
ABS_CHUNK_ROWS = 1 << 18


def abs_transpose_product(B, x: np.ndarray) -> np.ndarray:
    """``|B|^T x`` (entrywise absolute values) for a CSR ``B``, in chunks of rows
    that share B's index arrays: no copy of B (``abs(B.T)`` was one, 0.6 GB at a
    million tetrahedra)."""
    import scipy.sparse as sp

    B = B.tocsr()
    out = np.zeros(B.shape[1])
    for s in range(0, B.shape[0], ABS_CHUNK_ROWS):
        e = min(s + ABS_CHUNK_ROWS, B.shape[0])
        p0, p1 = B.indptr[s], B.indptr[e]
        block = sp.csr_matrix((np.abs(B.data[p0:p1]), B.indices[p0:p1], B.indptr[s:e + 1] - p0),
                              shape=(e - s, B.shape[1]))
        out += block.T @ x[s:e]
    return out


def abs_product(B, x: np.ndarray) -> np.ndarray:
    """``|B| x`` for a CSR ``B``, in the chunks of rows of :func:`abs_transpose_product`
    (row by row the same sums as one product: the same values; a copy of ``|B|``
    at a million tetrahedra was 0.6 GB of fresh pages, 0.37 s per certificate at 375k)."""
    import scipy.sparse as sp

    out = np.empty(B.shape[0])
    for s in range(0, B.shape[0], ABS_CHUNK_ROWS):
        e = min(s + ABS_CHUNK_ROWS, B.shape[0])
        p0, p1 = B.indptr[s], B.indptr[e]
        out[s:e] = sp.csr_matrix((np.abs(B.data[p0:p1]), B.indices[p0:p1], B.indptr[s:e + 1] - p0),
                                 shape=(e - s, B.shape[1])) @ x
    return out


def shaped(a, shape: tuple[int, ...], name: str) -> np.ndarray:
    """``a`` as a float array of ``shape``, given in that shape or flat (its entries in
    row-major order), or an :class:`~elastoplast.errors.InputError` naming ``name`` and the
    shape expected: for anything that is not numbers (strings, ``None``, objects), for a
    wrong size, and for another layout of the right size (a transposed ``u``, shape
    (d, n_nodes), would be read with its components interleaved: refused, never reshaped).
    NaN and infinite entries pass: the certificate of such a candidate is NaN, never small."""
    size = int(np.prod(shape))
    arr = check_array(name, a)
    if arr.size != size:
        raise InputError(name, f"expected {size} values {shape}, got {arr.size} {arr.shape}")
    if arr.shape != tuple(shape) and arr.ndim != 1:
        raise InputError(name, f"expected shape {shape} (or {size} values flat), got {arr.shape}: another layout is "
                               "not reshaped (a transposed array would be read with its entries interleaved)")
    return arr.reshape(shape)


def real_number(name: str, value) -> float:
    """``value`` as a float: a real number (a numpy scalar, a 0-d array) but not a
    boolean or a string, else an InputError naming ``name``. NaN and infinity pass,
    as in :func:`shaped`."""
    if isinstance(value, np.ndarray) and value.shape == () and value.dtype.kind in "iuf":
        value = value.item()
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise InputError(name, f"expected a number, got {short_repr(value)}")
    try:
        return float(value)
    except OverflowError:  # an integer beyond any float
        raise InputError(name, f"expected a number within the float range, got {short_repr(value)}") from None


def propagated(disc: Discretization, u_free: np.ndarray) -> np.ndarray:
    """``|B|^T |T| |C| |B| |u|``: at each dof, how large the terms of ``r`` would be
    if every displacement entered with its full size. Rounding ``u`` by one
    epsilon moves ``r`` by at most this times epsilon, however small the strains
    (a nearly rigid displacement of many times the strain scale cancels in
    ``B u``, its rounding does not)."""
    absC = np.abs(disc.material.stiffness(disc.dim))
    B = disc.B.tocsr()
    scale = abs_product(B, np.abs(u_free)).reshape(disc.n_elements, disc.k) @ absC
    return abs_transpose_product(B, (scale * disc.volumes[:, None]).ravel())


def _contact_rows(disc: Discretization):
    """The rows of ``|B|`` that :func:`propagated_at_contact` reads, kept per discretisation
    (a weak reference: the cache dies with it): the elements that touch a vertical
    contact dof, their rows of ``|B|`` (CSR) and of ``|B|`` restricted to the contact
    columns (CSC), and their volumes."""
    import weakref

    import scipy.sparse as sp

    hit = _CONTACT_ROWS.get(id(disc))
    if hit is not None and hit[0]() is disc:
        return hit[1]
    N = disc.N.tocsr()
    cdofs = N.indices[N.indptr[:-1]]
    B = disc.B.tocsr()
    touches = np.zeros(B.shape[1], dtype=bool)
    touches[cdofs] = True
    rows_hit = np.zeros(B.shape[0], dtype=bool)
    for s in range(0, B.shape[0], ABS_CHUNK_ROWS):  # the rows with an entry in a contact column
        e = min(s + ABS_CHUNK_ROWS, B.shape[0])
        p0, p1 = B.indptr[s], B.indptr[e]
        counts = np.add.reduceat(touches[B.indices[p0:p1]], B.indptr[s:e] - p0) if p1 > p0 else np.zeros(e - s)
        counts[np.diff(B.indptr[s:e + 1]) == 0] = 0
        rows_hit[s:e] = counts > 0
    elements = np.unique(np.flatnonzero(rows_hit) // disc.k)
    rows = (elements[:, None] * disc.k + np.arange(disc.k)).ravel()
    Be = B[rows]
    Be = sp.csr_matrix((np.abs(Be.data), Be.indices, Be.indptr), shape=Be.shape)
    Bc = Be[:, cdofs].tocsc()
    value = (elements, Be, Bc, disc.volumes[elements], N.data)
    _CONTACT_ROWS.clear()  # one discretisation at a time: the last one certified
    _CONTACT_ROWS[id(disc)] = (weakref.ref(disc), value)
    return value


_CONTACT_ROWS: dict = {}


def propagated_at_contact(disc: Discretization, u_free: np.ndarray) -> np.ndarray:
    """``N @ propagated(disc, u_free)``: :func:`propagated` at the vertical contact dofs
    (the only place the certificate reads it), from the elements touching them alone:
    the same sums of the same terms (their order changes only where a contact dof's rows
    straddle a chunk of :func:`abs_transpose_product`: the last bit of a round-off
    threshold). Measured at 375k tetrahedra: 0.47 s -> 0.01 s per certificate."""
    elements, Be, Bc, volumes, signs = _contact_rows(disc)
    absC = np.abs(disc.material.stiffness(disc.dim))
    scale = (Be @ np.abs(u_free)).reshape(elements.size, disc.k) @ absC
    return signs * (Bc.T @ (scale * volumes[:, None]).ravel())


def certify(
    disc: Discretization,
    sigma: np.ndarray,
    xi: np.ndarray,
    u: np.ndarray,
    U: float,
    contact_force: np.ndarray | None = None,
) -> KKTResiduals:
    """KKT residuals of the candidate; ``u`` is nodal ``(n_nodes, d)``.

    The candidate's origin does not matter: no solver output other than these
    arrays is used. Arguments of the wrong type or shape are refused with an
    :class:`~elastoplast.errors.InputError` naming them (:func:`shaped`,
    :func:`real_number`); non-finite values are admitted and give NaN (or infinite)
    residuals, without floating-point warnings.
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    sigma = shaped(sigma, (disc.n_elements, disc.k), "sigma")
    xi = shaped(xi, (disc.n_elements,), "xi")
    u_all = shaped(u, (disc.mesh.n_nodes, disc.dim), "u").reshape(-1)
    U = real_number("U", U)
    lam = None if contact_force is None else shaped(contact_force, (disc.n_contact,), "contact_force")
    with np.errstate(all="ignore"):  # the residuals say it (NaN is never small), no warning on top
        return _residuals(disc, sigma, xi, u_all, U, lam)


def _residuals(disc: Discretization, sigma: np.ndarray, xi: np.ndarray, u_all: np.ndarray, U: float,
               lam: np.ndarray | None) -> KKTResiduals:
    """:func:`certify` on checked arguments."""
    u_free = u_all[disc.free]
    F = disc.force

    sigma_R, xi_R, _ = return_mapping(disc.material, disc.strain(u_free), disc.state)
    ref = energy_density(disc, sigma_R, xi_R)
    diff = energy_density(disc, sigma - sigma_R, xi - xi_R)
    tiny = np.finfo(float).tiny
    constitutive = np.sqrt((disc.volumes @ diff) / max(disc.volumes @ ref, tiny))
    constitutive_max = np.sqrt(diff.max() / max(ref.max(), tiny))

    r = disc.internal_force(sigma)
    lam = disc.N @ r if lam is None else lam
    magnitude = abs_transpose_product(disc.B, np.abs(sigma * disc.volumes[:, None]).ravel())
    res = r - disc.N.T @ lam
    equilibrium = np.linalg.norm(res) / max(np.linalg.norm(magnitude), np.finfo(float).tiny)

    g = gaps(disc, u_free, U)
    delta = max(abs(U), np.abs(u_all).max(initial=0.0), np.finfo(float).tiny,
                0.0 if disc.state is None else disc.state.displacement)  # a step: the total displacement's scale
    # a contact force within the round-off of the sum that computes r there is zero to
    # working precision: it must not count against complementarity at a wide-open gap
    resolved = np.where(np.abs(lam) > ROUND_OFF * (disc.N @ magnitude + propagated_at_contact(disc, u_free)), lam, 0.0)
    return KKTResiduals(
        constitutive=float(constitutive),
        constitutive_max=float(constitutive_max),
        equilibrium=float(equilibrium),
        force_balance=float(abs(lam.sum() - F) / F),
        sign=float(np.maximum(-lam, 0.0).sum() / F),
        penetration=float(np.maximum(-g, 0.0).max(initial=0.0) / delta),
        complementarity=float(np.abs(resolved * g).sum() / (F * delta)),
        dirichlet=float(np.abs(u_all[disc.fixed]).max(initial=0.0) / delta),
    )
