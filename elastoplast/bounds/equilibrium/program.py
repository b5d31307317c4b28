"""The lower bound's conic program: the equilibrium element in energy-normalised unknowns (docs/bounds.md).

Unknowns are the vertex values of linear stresses (and hardening stresses when H > 0)
per element and the contact tractions at the vertices of the contact facets; the rows
are equilibrium in each element, traction continuity across interior facets, the
boundary conditions, the force balance, and one yield cone per element vertex.

Axisymmetric models (:class:`Ring`) use the same program in other unknowns: at each
element vertex the stress ``s_a = (tau_a / r_a, sigma_thth)`` (``tau = r sigma``, docs/bounds.md),
so that the yield cones are plane strain's; ``tau_a = r_a s_a`` vanishes on the axis by
construction. Equilibrium becomes ``sum_a r_a N(grad b_a) s_a = (sigma_thth, 0)``; the traction
rows of ``tau n`` at a facet vertex off the axis are those of ``s n`` (divided by ``r_a > 0``)
and are dropped on the axis (tau vanishes there on both sides); the contact unknowns are the
pressures p (``tau n = r p e_z``: ``s n = p e_z``), the force balance ``2 pi int r p = F``;
rows tie the hoop slot of the vertices off the axis of each element (sigma_thth constant);
the energy is the vertex rule, ``2 pi |T| r_a / 3`` per vertex. The vertices on the axis carry
no energy and no condition: they are given a small energy weight only to keep the program
bounded (their s stays 0 and never enters the field)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from elastoplast.bounds.static import mass_matrix, traction_operator
from elastoplast.fem.discretize import Discretization
from elastoplast.mesh.topology import FacetTopology
from elastoplast.fem.stress_form import contact_sign_rows, volume_weights, yield_rows
from elastoplast.solvers.backends import clarabel_rows


@dataclass(frozen=True)
class Ring:
    """An axisymmetric model's data for the program, in its length unit: ``r (n_el, 3)`` the
    vertex radii (``<= 0``: on the axis) and ``area (n_el,)`` the triangles' areas ``|T|``."""

    r: np.ndarray
    area: np.ndarray

    @property
    def off_axis(self) -> np.ndarray:
        return self.r > 0


@dataclass(frozen=True)
class Program:
    """Clarabel data ``(P, q, A, b, cones)``; the first ``n_eq`` rows of A are the
    equality rows; ``weights`` are the element weights ``w_T = sqrt(|T|/mean|T|)`` of
    the unknowns ``tau_hat = w_T tau``, ``eta_hat = w_T eta``, ``lam_hat = w_T lam``
    (T the element of the contact facet); ``cols`` the column ranges by name."""

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    b: np.ndarray
    cones: list
    n_eq: int
    weights: np.ndarray
    lam_weights: np.ndarray
    cols: dict


def _block_coo(rows: np.ndarray, cols: np.ndarray, vals: np.ndarray):
    """Flatten broadcastable index/value arrays, dropping structural zeros."""
    rows, cols, vals = (np.broadcast_to(a, np.broadcast_shapes(rows.shape, cols.shape, vals.shape)).ravel()
                        for a in (rows, cols, vals))
    keep = vals != 0.0
    return rows[keep], cols[keep], vals[keep]


def equality_rows(nd: Discretization, topo: FacetTopology, grads: np.ndarray, n_cols: int,
                  lam_col: int, force_col: int | None, ring: Ring | None = None):
    """The equality rows ``A x = b`` in energy-normalised unknowns, every row a force.

    With ``G_ea = (|T_e| / w_e) N(grad b_a)`` (d x k; note ``|f_i| n_i / d = -|T| grad b_i``
    for the facet opposite vertex i, n its outward unit normal):

    * element e: ``sum_a G_ea tau_hat_ea = 0`` (``|T| div tau = 0``);
    * interior facet, at each facet vertex: ``G_{T,i} tau_hat_{T,a} + G_{T',i'}
      tau_hat_{T',a'} = 0`` (the outward tractions times ``|f|/d`` cancel);
    * boundary facet opposite vertex i of T, at facet vertex a, component j:
      ``(G_{T,i} tau_hat_{T,a})_j = 0`` where the traction must vanish, and
      ``(G_{T,i} tau_hat_{T,a})_d + (|f|/d) / w_T lam_hat_a = 0`` on Γ0;
    * ``sum_f (|f|/d) sum_a lam_a = F`` (or ``- F_hat`` in column ``force_col``).

    ``ring``: the axisymmetric rows of the module docstring (|T| the triangles' areas,
    equilibrium rows weighted by ``r_a`` with the hoop body force, traction rows on the
    axis dropped, the force row weighted by ``2 pi r_a``; rows left empty are removed).
    """
    d, k, n = nd.dim, nd.k, nd.n_elements
    w = np.sqrt(nd.volumes / nd.volumes.mean())
    measure = nd.volumes if ring is None else ring.area
    G = (measure / w)[:, None, None, None] * traction_operator(grads)  # (n, d+1, d, k)
    keep_vertex = np.ones((n, d + 1)) if ring is None else ring.off_axis.astype(float)
    ck = np.arange(k)
    cr = np.arange(d)

    def tau_cols(e, a):
        return ((e * (d + 1) + a) * k)[..., None, None] + ck  # (..., 1, k)

    parts = []
    # element equilibrium
    e = np.arange(n)[:, None]
    a = np.arange(d + 1)[None, :]
    G_eq = G if ring is None else G * ring.r[:, :, None, None]
    parts.append(_block_coo((e * d)[:, :, None, None] + cr[:, None], tau_cols(e, a), G_eq))
    if ring is not None:  # - |T| (sigma_thth, 0), sigma_thth the mean hoop slot off the axis
        share = -(measure / w)[:, None] * keep_vertex / keep_vertex.sum(axis=1, keepdims=True)
        parts.append(_block_coo(e * d, tau_cols(e, a)[..., 0, 2], share))
    row = n * d
    # interior facets
    IE, IL, IV = topo.interior_elements, topo.interior_local, topo.interior_vertices
    n_if = IE.shape[0]
    f = np.arange(n_if)[:, None, None]
    j = np.arange(d)[None, None, :]
    rows = row + ((f * d + j) * d)[..., None, None] + cr[:, None]  # (n_if, 1, d, d, 1)
    Gf = G[IE, IL][:, :, None] * keep_vertex[IE[:, :, None], IV][..., None, None]  # (n_if, 2, 1, d, k)
    parts.append(_block_coo(rows, tau_cols(IE[:, :, None], IV), Gf))
    row += n_if * d * d
    # boundary facets
    BE, BL, BV = topo.boundary_elements, topo.boundary_local, topo.boundary_vertices
    n_bf = BE.shape[0]
    cond = topo.zero_traction.copy()
    cond[:, -1] |= topo.contact
    keep = np.broadcast_to(cond[:, None, :], (n_bf, d, d))  # (facet, vertex, component)
    row_id = np.where(keep, row + np.cumsum(keep.ravel()).reshape(keep.shape) - 1, -1)
    Gb = G[BE, BL][:, None] * keep_vertex[BE[:, None], BV][..., None, None]  # (n_bf, d, d, k)
    r_, c_, v_ = _block_coo(row_id[..., None], tau_cols(BE[:, None], BV), Gb)
    parts.append((r_[r_ >= 0], c_[r_ >= 0], v_[r_ >= 0]))
    row += int(keep.sum())
    # contact pressure in the vertical rows of the Γ0 facets, and the force balance
    ci = topo.contact_index
    share = (measure[BE[ci]] * np.linalg.norm(grads[BE[ci], BL[ci]], axis=1) / w[BE[ci]])  # (|f|/d) / w_T
    lam_cols = lam_col + np.arange(ci.size * d).reshape(-1, d)
    parts.append((row_id[ci, :, -1].ravel(), lam_cols.ravel(), np.repeat(share, d)))
    force_share = np.repeat(share, d)
    if ring is not None:
        force_share = force_share * 2.0 * np.pi * np.maximum(ring.r[BE[ci][:, None], BV[ci]], 0.0).ravel()
    parts.append((np.full(lam_cols.size, row), lam_cols.ravel(), force_share))
    b = np.zeros(row + 1)
    if force_col is None:
        b[row] = nd.force
    else:
        parts.append((np.array([row]), np.array([force_col]), np.array([-1.0])))
    r, c, v = (np.concatenate(x) for x in zip(*parts))
    A = sp.csr_matrix((v, (r, c)), shape=(row + 1, n_cols))
    if ring is not None:  # the rows of tractions on the axis, emptied above
        used = (np.diff(A.indptr) > 0) | (b != 0)
        A, b = A[used], b[used]
    return A.tocsc(), b


def hoop_rows(ring: Ring, w: np.ndarray, k: int, n_cols: int):
    """``|T| / w_T (s_hat_a - s_hat_b)_thth = 0`` for consecutive vertices off the axis of
    each element: sigma_thth constant per element."""
    n, nv = ring.r.shape
    rows, cols, vals = [], [], []
    row = 0
    for a in range(nv):
        for b in range(a + 1, nv):  # a chain: each pair (a, b) with no vertex off the axis between them
            between = ring.off_axis[:, a + 1:b].any(axis=1) if b > a + 1 else np.zeros(n, dtype=bool)
            e = np.flatnonzero(ring.off_axis[:, a] & ring.off_axis[:, b] & ~between)
            for vertex, sign in ((a, 1.0), (b, -1.0)):
                rows.append(row + np.arange(e.size))
                cols.append((e * nv + vertex) * k + 2)
                vals.append(sign * ring.area[e] / w[e])
            row += e.size
    return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(row, n_cols))


def lower_bound_program(nd: Discretization, topo: FacetTopology, grads: np.ndarray, q_psi: np.ndarray,
                        limit: bool = False, with_yield: bool = True, ring: Ring | None = None) -> Program:
    """The equilibrium-element program on the O(1) problem ``nd`` (see
    :func:`~elastoplast.fem.discretize.nondimensionalize`); ``grads`` the barycentric
    gradients in its length unit, ``q_psi`` the obstacle weights in its units.

    Energy mode: minimise ``1/2 sum_T sum_ab M_ab (tau_hat_a A tau_hat_b + eta_hat_a
    eta_hat_b / H) + sum q lam`` (the exact J: ``|T| / w_T^2 = 1`` per element).
    Limit mode: minimise ``-F_hat`` with eta = 0 and no energy. Cones: ``lam_hat >= 0``,
    and ``sqrt(3/2)|dev tau_hat_a| <= w_T sigma_y + eta_hat_a`` at each element vertex
    (the per-element cone of (S), :func:`~elastoplast.fem.stress_form.yield_rows`, one per
    element vertex, each with its element's weight ``w_T``).
    ``ring``: the axisymmetric variant of the module docstring (energy mode only).
    """
    import clarabel

    d, k, n, m = nd.dim, nd.k, nd.n_elements, nd.material
    nv = n * (d + 1)
    has_eta = not limit and m.hardening > 0
    n_lam = topo.contact_index.size * d
    eta_col = nv * k
    lam_col = eta_col + (nv if has_eta else 0)
    n_cols = lam_col + n_lam + (1 if limit else 0)
    force_col = n_cols - 1 if limit else None
    w = np.sqrt(nd.volumes / nd.volumes.mean())
    lam_w = np.repeat(w[topo.boundary_elements[topo.contact_index]], d)

    A_eq, b_eq = equality_rows(nd, topo, grads, n_cols, lam_col, force_col, ring)
    if ring is not None:
        if limit:
            raise ValueError("the axisymmetric program has no limit mode")
        A_eq = sp.vstack([A_eq, hoop_rows(ring, w, k, n_cols)], format="csc")
        b_eq = np.concatenate([b_eq, np.zeros(A_eq.shape[0] - b_eq.size)])
    groups = [contact_sign_rows(n_lam, lam_col)]
    if with_yield:  # the yield cones of (S) at the element vertices: w_T at each vertex of T
        vertex_weights = volume_weights(np.repeat(nd.volumes, d + 1))  # the mean over vertices, as always
        groups.append(yield_rows(k, vertex_weights, m.yield_stress, 0, eta_col if has_eta else None))
    more, more_rhs, more_cones = clarabel_rows(groups, n_cols)
    blocks = [A_eq, *more]
    rhs = [b_eq, *more_rhs]
    cones = [clarabel.ZeroConeT(b_eq.size), *more_cones]

    M = mass_matrix(d)
    q = np.zeros(n_cols)
    if limit:
        P = sp.csc_matrix((n_cols, n_cols))
        q[force_col] = -1.0
    elif ring is None:
        pb = [sp.kron(sp.eye(n), sp.csr_matrix(np.triu(np.kron(M, m.compliance(d)))))]
        if has_eta:
            pb.append(sp.kron(sp.eye(n), sp.csr_matrix(np.triu(M) / m.hardening)))
        pb.append(sp.csr_matrix((n_lam, n_lam)))
        P = sp.block_diag(pb, format="csc")
        q[lam_col: lam_col + n_lam] = q_psi.ravel() / lam_w
    else:  # the vertex rule, 2 pi |T| r_a / 3 per vertex (on the axis: the element's mean r, a regularisation)
        r_mean = np.maximum(ring.r, 0.0).mean(axis=1, keepdims=True)
        c = 2.0 * np.pi * ring.area[:, None] * np.where(ring.off_axis, ring.r, r_mean) / (3.0 * w[:, None] ** 2)
        pb = [sp.kron(sp.diags(c.ravel()), sp.csr_matrix(np.triu(m.compliance(d))))]
        if has_eta:
            pb.append(sp.diags(c.ravel() / m.hardening))
        pb.append(sp.csr_matrix((n_lam, n_lam)))
        P = sp.block_diag(pb, format="csc")
        ci = topo.contact_index
        r_contact = np.maximum(ring.r[topo.boundary_elements[ci][:, None], topo.boundary_vertices[ci]], 0.0)
        q[lam_col: lam_col + n_lam] = 2.0 * np.pi * (q_psi * r_contact).ravel() / lam_w
    cols = dict(tau=slice(0, nv * k), eta=slice(eta_col, lam_col) if has_eta else None,
                lam=slice(lam_col, lam_col + n_lam), force=force_col)
    return Program(P, q, sp.vstack(blocks, format="csc"), np.concatenate(rhs), cones, b_eq.size, w, lam_w, cols)
