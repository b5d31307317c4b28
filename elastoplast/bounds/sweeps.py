"""Patch-local complementary-energy minimisation that keeps a field exactly admissible (docs/bounds.md).

The field is given by its linear facet tractions (balanced on every element) and the
element lift (:mod:`elastoplast.bounds.lift`). On the star of a vertex p, a correction of
the tractions on the facets through p, with every element of the star still balanced,
changes the field only in the star and keeps it statically admissible (the facets
opposite p, on the star's boundary, keep their tractions; Γ0 facets and prescribed
components of boundary facets are not touched, so ``int lam = F`` and ``lam >= 0``
stay as they are). Each patch solves

    minimise  J_star(t + Z y)   over y,   Z an orthonormal basis of {x : C x = 0}

(C the star elements' force and moment balance rows, row-normalised; Z from the SVD of C,
so ``C Z y`` is round-off of the size of ``|y|``, whatever the conditioning) by a
Gauss–Newton step (exact for the elastic part; the plastic part ``int eta^2 / 2H`` with
``eta = max(0, vm - sigma_y)`` at the sub-element vertices is linearised through
``grad vm``), kept only where it lowers J_star. Stars of one colour share no element (a
colouring of the node graph): their problems are independent and solved as one batch of
dense matrices (``np.linalg.svd`` and ``np.linalg.solve`` on stacks), the star topology
and null-space bases computed once for all sweeps. J never increases.

:func:`repair_balance` (the round-off repair) projects the element balance rows of the
tractions back to zero, colour by colour: the stars of one colour are disjoint, so the
rows and unknowns of one colour form a block-diagonal system, projected with
:func:`~elastoplast.bounds.repair.project_affine` as the global program's repair does."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from elastoplast.bounds.equilibrate import Faces, element_tractions, segment_ranges
from elastoplast.bounds.lift import MANDEL_PAIRS, ElementMaps, mandel_to_tensor, reference_lift, tensor_to_mandel
from elastoplast.bounds.lift import balance_matrices as vertex_balance_matrices
from elastoplast.bounds.repair import project_affine
from elastoplast.bounds.static import mass_matrix
from elastoplast.fem.material import Material, deviator_matrix, von_mises

#: bytes of the largest dense temporary of one batch of stars (the batch size follows from it)
BATCH_BYTES = 1 << 27
#: singular values of a star's row-normalised balance matrix below this (relative to the
#: largest) span its self-equilibrated corrections
NULL_RCOND = 1e-9
#: step lengths tried per patch (the first that lowers J_star is kept)
STEPS = (1.0, 0.5, 0.25)
#: passes of :func:`repair_balance` at most (each visits every colour)
REPAIR_PASSES = 4
#: the element imbalance (relative to ``|C_e| max|t|``) below which the repair stops: round-off
#: (the lift leaves an element's imbalance on its facets in the physical metric,
#: :func:`~elastoplast.bounds.lift.lift`; before its refinement it amplified it up to 1e4
#: times on elements of condition number 100-150)
REPAIR_TOL = 2e-15


def node_colours(cells: np.ndarray, n_nodes: int, seed: int = 0) -> np.ndarray:
    """Colours of the nodes such that no element has two nodes of one colour
    (Jones–Plassmann: each round colours the uncoloured nodes whose random priority beats
    every uncoloured neighbour's)."""
    d1 = cells.shape[1]
    r = np.repeat(cells, d1, axis=1).ravel()
    c = np.tile(cells, (1, d1)).ravel()
    keep = r != c
    pairs = np.unique(r[keep] * n_nodes + c[keep])
    r, c = pairs // n_nodes, pairs % n_nodes
    prio = np.random.default_rng(seed).permutation(n_nodes).astype(float) + 1.0
    colour = -np.ones(n_nodes, dtype=np.int64)
    k = 0
    while np.any(colour < 0):
        live = np.where(colour < 0, prio, 0.0)
        best = np.zeros(n_nodes)
        np.maximum.at(best, r, live[c])
        pick = (colour < 0) & (live > best)
        colour[pick] = k
        k += 1
    return colour


def stress_map(dim: int, material: Material) -> np.ndarray:
    """``(k, m)``: full Mandel stress from the lifted in-plane components (plane strain:
    ``tau33 = nu (tau11 + tau22)``)."""
    if dim == 3:
        return np.eye(6)
    T = np.zeros((4, 3))
    T[[0, 1, 3], [0, 1, 2]] = 1.0
    T[2, :2] = material.nu
    return T


def lift_matrices(maps: ElementMaps, elems: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``(len(elems), d+1, d+1, k, (d+1)(d+1)d)``: full Mandel sub-vertex stresses from the
    element's outward vertex tractions (the linear map of :func:`~elastoplast.bounds.lift.lift`)."""
    d = maps.J.shape[1]
    d1 = d + 1
    ref = reference_lift(d)
    m = len(MANDEL_PAIRS[d])
    J, Jinv, det = maps.J[elems], maps.Jinv[elems], maps.det[elems]
    n = elems.size
    E = mandel_to_tensor(np.eye(m), d)  # (q, d, d)
    P = tensor_to_mandel(np.einsum("nij,qjk,nlk->nqil", J, E, J), d) / det[:, None, None]  # (n, q, p)
    TP = np.einsum("kp,nqp->nkq", T, P)  # (n, k, q)
    scale = maps.facet_areas[elems] / ref.areas  # (n, f)
    # reference tractions: t_hat[f, a, i] = scale_f sum_j Jinv[i, j] t[f, a, j]
    R = np.matmul(ref.matrix.reshape(1, -1, d), Jinv)  # (n, s b q f a, j)
    R = R.reshape(n, d1 * d1, m, d1, d1 * d) * scale[:, None, None, :, None]
    L = np.matmul(TP[:, None], R.reshape(n, d1 * d1, m, -1))  # (n, s b, k, f a j)
    return L.reshape(n, d1, d1, T.shape[0], -1)


def balance_matrices(points: np.ndarray, cells: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """``(n, nb, (d+1)(d+1)d)``: force and moment (about the centroid) of an element's outward
    vertex tractions ``t[i, a, j]`` (zero weight where a == i; :func:`~elastoplast.bounds.lift.balance_matrices`)."""
    return vertex_balance_matrices(points[cells], areas)


def element_energy(sig: np.ndarray, w: np.ndarray, MA: np.ndarray, M: np.ndarray, sy: float, H: float):
    """``J_e`` of sub-vertex stresses ``sig (n, s, b, k)`` (sub volumes ``w (n,)``; ``MA = M (x) A``)."""
    n, s = sig.shape[:2]
    flat = sig.reshape(n, s, -1)
    el = 0.5 * w * np.einsum("nsx,nsx->n", flat, flat @ MA.T)
    if H > 0:
        eta = np.maximum(von_mises(sig) - sy, 0.0)
        el = el + 0.5 / H * w * np.einsum("nsb,nsb->n", eta, eta @ M)
    return el


@dataclass
class StarBatch:
    """The stars of one batch (equal colour): ``E (m, ne)`` their elements (padded with 0,
    ``valid``), ``fi (m, ne, d+1)`` those elements' facets, ``slot`` the facet slots of the
    element vertices, ``xidx, sgn (m, ne, nte)`` the star dof and sign of every element
    traction dof (sign 0: not in the star), ``Fm (m, nf)`` the star's facets (-1 padding),
    ``gdof (m, nx)`` the global traction dof of each star dof (-1: none or fixed),
    ``Z (m, nx, r)`` the orthonormal self-equilibrated basis (zero columns pad), ``C``
    the elements' balance rows ``(m, ne, nb, nte)``."""

    E: np.ndarray
    valid: np.ndarray
    fi: np.ndarray
    slot: np.ndarray
    xidx: np.ndarray
    sgn: np.ndarray
    Fm: np.ndarray
    gdof: np.ndarray
    C: np.ndarray
    Z: np.ndarray | None = None


def star_batches(points, cells, maps: ElementMaps, faces: Faces, colours: np.ndarray, free_comp: np.ndarray,
                 with_basis: bool = True) -> list[StarBatch]:
    """The :class:`StarBatch` es of every colour, in colour order."""
    n, d1 = cells.shape
    d = d1 - 1
    nte = d1 * d1 * d
    n_nodes = colours.size
    eq_node = cells.ravel()
    eq_order = np.argsort(eq_node, kind="stable")
    eq_count = np.bincount(eq_node, minlength=n_nodes)
    eq_start = np.concatenate([[0], np.cumsum(eq_count)])
    fn = faces.nodes.ravel()
    f_order = np.argsort(fn, kind="stable")
    f_count = np.bincount(fn, minlength=n_nodes)
    f_start = np.concatenate([[0], np.cumsum(f_count)])
    out = []
    for c in range(int(colours.max()) + 1):
        group = np.flatnonzero((colours == c) & (eq_count > 0))
        if group.size == 0:
            continue
        ne_max = int(eq_count[group].max())
        nx_max = int(f_count[group].max()) * d * d
        size = max(1, BATCH_BYTES // (8 * ne_max * nte * nx_max))
        for c0 in range(0, group.size, size):
            nodes = group[c0: c0 + size]
            out.append(_star_batch(nodes, points, cells, maps, faces, free_comp, eq_order, eq_count, eq_start,
                                   f_order, f_count, f_start, with_basis))
    return out


def _star_batch(nodes, points, cells, maps, faces, free_comp, eq_order, eq_count, eq_start, f_order, f_count,
                f_start, with_basis) -> StarBatch:
    n, d1 = cells.shape
    d = d1 - 1
    nte = d1 * d1 * d
    m = nodes.size
    ne = int(eq_count[nodes].max())
    nf = int(f_count[nodes].max())
    F = faces.nodes.shape[0]
    el_cnt = eq_count[nodes]
    ids = eq_order[np.repeat(eq_start[nodes], el_cnt) + segment_ranges(el_cnt)]
    srow, scol = np.repeat(np.arange(m), el_cnt), segment_ranges(el_cnt)
    E = np.zeros((m, ne), dtype=np.int64)
    valid = np.zeros((m, ne), dtype=bool)
    E[srow, scol] = ids // d1
    valid[srow, scol] = True
    Aloc = np.zeros((m, ne), dtype=np.int64)
    Aloc[srow, scol] = ids % d1
    fc = f_count[nodes]
    Fm = -np.ones((m, nf), dtype=np.int64)
    Fm[np.repeat(np.arange(m), fc), segment_ranges(fc)] = f_order[np.repeat(f_start[nodes], fc) + segment_ranges(fc)] // d
    # local index of each element facet in its star (sorted keys star * F + facet)
    Fkeys = np.where(Fm >= 0, np.arange(m)[:, None] * F + Fm, -1).ravel()
    order = np.argsort(Fkeys)
    sorted_keys = Fkeys[order]
    fi = faces.face[E]  # (m, ne, d+1)
    key = np.arange(m)[:, None, None] * F + fi
    pos = order[np.minimum(np.searchsorted(sorted_keys, key), sorted_keys.size - 1)] % nf
    through = (np.arange(d1)[None, None, :] != Aloc[:, :, None]) & valid[:, :, None]
    slot = faces.slot[E]  # (m, ne, i, b)
    xidx = (pos[:, :, :, None] * d + np.where(slot >= 0, slot, 0))[..., None] * d + np.arange(d)
    ok = through[:, :, :, None, None] & (slot >= 0)[..., None] & free_comp[fi][:, :, :, None, :]
    sgn = np.where(ok, faces.sign[E][:, :, :, None, None], 0.0).reshape(m, ne, nte)
    nx = nf * d * d
    xidx = np.where(ok, xidx, nx).reshape(m, ne, nte)  # nx: a dummy column
    gdof = np.where(Fm[:, :, None, None] >= 0, (Fm[:, :, None, None] * d + np.arange(d)[:, None]) * d + np.arange(d),
                    -1).reshape(m, nx)
    C = balance_matrices(points, cells[E.ravel()], maps.facet_areas[E.ravel()]).reshape(m, ne, -1, nte)
    C = C * valid[:, :, None, None]
    used = np.zeros((m, nx + 1), dtype=bool)
    on = (sgn != 0).ravel()
    used[np.repeat(np.arange(m), ne * nte)[on], xidx.ravel()[on]] = True
    gdof = np.where(used[:, :nx], gdof, -1)
    batch = StarBatch(E, valid, fi, slot, xidx, sgn, Fm, gdof, C)
    if with_basis:
        batch.Z = _null_basis(batch, nx, used[:, :nx])
    return batch


def star_rows(b: StarBatch, nx: int) -> np.ndarray:
    """``(m, ne nb, nx)``: the balance rows of the star's elements on its dofs."""
    m, ne, nb, nte = b.C.shape
    Cs = np.zeros((m, ne, nb, nx + 1))
    mi = np.arange(m)[:, None, None, None]
    ei = np.arange(ne)[None, :, None, None]
    ri = np.arange(nb)[None, None, :, None]
    Cs[mi, ei, ri, b.xidx[:, :, None, :]] = b.sgn[:, :, None, :] * b.C  # one star dof per element dof
    Cs[..., nx] = 0.0
    return Cs[..., :nx].reshape(m, ne * nb, nx)


def _null_basis(b: StarBatch, nx: int, used: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the used star dofs with zero balance rows (SVD of the
    row-normalised rows stacked over the identity rows of the unused dofs)."""
    Cs = star_rows(b, nx)
    norms = np.linalg.norm(Cs, axis=2, keepdims=True)
    Cs = Cs / np.where(norms > 0, norms, 1.0)
    m = Cs.shape[0]
    ext = np.concatenate([Cs, np.eye(nx)[None] * (~used)[:, :, None]], axis=1)
    _, sv, Vt = np.linalg.svd(ext, full_matrices=False)
    svf = np.zeros((m, nx))
    svf[:, : sv.shape[1]] = sv
    live = svf <= NULL_RCOND * np.maximum(sv[:, :1], 1e-300)
    r = int(live.sum(axis=1).max(initial=0))
    Z = np.swapaxes(Vt, 1, 2)[:, :, nx - r:] * live[:, None, nx - r:]
    Z[~used] = 0.0
    return Z


def sweep(points: np.ndarray, cells: np.ndarray, maps: ElementMaps, faces: Faces, t: np.ndarray, volumes: np.ndarray,
          material: Material, colours: np.ndarray, frozen: np.ndarray, n_sweeps: int = 3,
          offset: np.ndarray | None = None, batches: list[StarBatch] | None = None) -> np.ndarray:
    """``n_sweeps`` coloured sweeps over the vertex stars; returns the new facet tractions
    ``(F, d, d)``. ``frozen (F,)`` marks facets never changed (Γ0); ``offset (n,)`` the
    plane-strain tau33 offset of each element (:func:`~elastoplast.bounds.local.out_of_plane_offset`)."""
    n, d1 = cells.shape
    d = d1 - 1
    T = stress_map(d, material)
    k = T.shape[0]
    A = material.compliance(d)
    M = mass_matrix(d)
    ctx = dict(T=T, A=A, M=M, MA=np.kron(M, A), sy=material.yield_stress, H=material.hardening,
               Dv=deviator_matrix(d), base=np.zeros((n, k)))
    if offset is not None and d == 2:
        ctx["base"][:, 2] = offset
    t = t.copy()
    if batches is None:
        batches = star_batches(points, cells, maps, faces, colours, sweep_free(faces, frozen))
    for _ in range(n_sweeps):
        for b in batches:
            _star_step(b, maps, faces, t, volumes, ctx)
    return t


def sweep_free(faces: Faces, frozen: np.ndarray) -> np.ndarray:
    """``(F, d)``: the traction components the sweeps may change."""
    free = faces.unknown.copy()
    free[frozen] = False
    return free


def batch_tractions(b: StarBatch, faces: Faces, t: np.ndarray) -> np.ndarray:
    """``(m ne, nte)``: the outward vertex tractions of the batch's elements."""
    slot = np.where(b.slot >= 0, b.slot, 0)
    te = t[b.fi[..., None], slot] * faces.sign[b.E][:, :, :, None, None]
    return np.where((b.slot >= 0)[..., None], te, 0.0).reshape(b.E.size, -1)


def _star_step(b: StarBatch, maps: ElementMaps, faces: Faces, t: np.ndarray, volumes: np.ndarray, ctx: dict):
    m, ne, nte = b.sgn.shape
    d1 = b.fi.shape[2]
    d = d1 - 1
    T, M, MA, sy, H = ctx["T"], ctx["M"], ctx["MA"], ctx["sy"], ctx["H"]
    k = T.shape[0]
    flat = b.E.ravel()
    N = flat.size
    L = lift_matrices(maps, flat, T).reshape(N, d1, d1 * k, nte)  # (N, s, b k, x)
    w = (volumes[flat] / d1) * b.valid.ravel()
    te = batch_tractions(b, faces, t)
    sig = (L @ te[:, None, :, None])[..., 0] + np.tile(ctx["base"][flat], (1, d1))[:, None, :]  # (N, s, b k)
    sig4 = sig.reshape(N, d1, d1, k)
    J0 = element_energy(sig4, w, MA, M, sy, H).reshape(m, ne).sum(axis=1)
    WL = np.matmul(MA, L) * w[:, None, None, None]
    gs = (sig @ MA.T) * w[:, None, None]  # (N, s, b k)
    Hel = np.matmul(L.reshape(N, -1, nte).transpose(0, 2, 1), WL.reshape(N, -1, nte))  # (N, x, x)
    if H > 0:
        vm = von_mises(sig4)
        eta = np.maximum(vm - sy, 0.0)
        nrm = 1.5 * (sig4 @ ctx["Dv"].T) / np.maximum(vm, 1e-300)[..., None]
        nrm = np.where((eta > 0)[..., None], nrm, 0.0)
        gs = gs + ((eta @ M)[..., None] * nrm * (w / H)[:, None, None, None]).reshape(N, d1, -1)
        Ln = np.einsum("nsbkx,nsbk->nsbx", L.reshape(N, d1, d1, k, nte), nrm)  # (N, s, b, x)
        Hel = Hel + np.matmul(Ln.reshape(N, -1, nte).transpose(0, 2, 1),
                              (M @ Ln).reshape(N, -1, nte) * (w / H)[:, None, None])
    ge = np.einsum("nsyx,nsy->nx", L, gs)
    Z = b.Z
    r = Z.shape[2]
    nx = Z.shape[1]
    Zp = np.concatenate([Z, np.zeros((m, 1, r))], axis=1)
    B = b.sgn.reshape(N, nte)[:, :, None] * Zp[np.repeat(np.arange(m), ne)[:, None], b.xidx.reshape(N, nte)]  # (N, x, r)
    HB = Hel @ B
    Hr = np.matmul(B.transpose(0, 2, 1).reshape(m, ne, r, nte).transpose(0, 2, 1, 3).reshape(m, r, ne * nte),
                   HB.reshape(m, ne * nte, r))
    gr = np.einsum("nxr,nx->nr", B, ge).reshape(m, ne, r).sum(axis=1)
    dead = np.abs(Z).max(axis=1) == 0  # padding columns
    Hr[:, np.arange(r), np.arange(r)] += dead
    scale = np.maximum(np.abs(Hr).max(axis=(1, 2)), 1e-300)
    y = np.linalg.solve(Hr / scale[:, None, None], (-gr / scale[:, None])[..., None])[..., 0]
    y = np.where(dead, 0.0, y)
    dsig = (L @ (B @ y.repeat(ne, axis=0)[:, :, None])[:, None, :, :])[..., 0]  # (N, s, b k)
    best = np.zeros(m)
    bestJ = J0.copy()
    for a in STEPS:
        Ja = element_energy((sig + a * dsig).reshape(N, d1, d1, k), w, MA, M, sy, H).reshape(m, ne).sum(1)
        better = (Ja < bestJ) & (best == 0)
        best[better] = a
        bestJ[better] = Ja[better]
    x = np.einsum("mxr,mr->mx", Z, y * best[:, None])
    ok = b.gdof >= 0
    t.reshape(-1)[b.gdof[ok]] += x[ok]


def element_imbalance(points, cells, maps: ElementMaps, faces: Faces, t: np.ndarray) -> np.ndarray:
    """``(n,)``: each element's largest balance-row residual of the tractions ``t``,
    relative to that row's norm times ``max |t|``."""
    C = balance_matrices(points, cells, maps.facet_areas)
    te = element_tractions(faces, t).reshape(cells.shape[0], -1)
    r = np.abs(np.einsum("nrx,nx->nr", C, te)) / np.maximum(np.linalg.norm(C, axis=2), 1e-300)
    return r.max(axis=1) / max(np.abs(t).max(initial=0.0), np.finfo(float).tiny)


def repair_balance(points, cells, maps: ElementMaps, faces: Faces, t: np.ndarray, batches: list[StarBatch],
                   free: np.ndarray, passes: int = REPAIR_PASSES) -> tuple[np.ndarray, float, float]:
    """The round-off repair of the element balance rows (module docstring): colour passes
    until the imbalance is below :data:`REPAIR_TOL`; what a star cannot carry (a star's net
    force and moment) moves to the next colour's stars, so an imbalance that is not
    star-local (not the sweeps' own round-off, which is) can remain after ``passes``: then
    one projection of all the element rows on the components ``free (F, d)``
    (:func:`global_balance_projection`). Returns ``(t, imbalance before, after, whether the
    whole-mesh projection ran)`` (:func:`element_imbalance`, largest)."""
    t = t.copy()
    before = after = float(element_imbalance(points, cells, maps, faces, t).max(initial=0.0))
    n, d1 = cells.shape
    for _ in range(passes):
        if after <= REPAIR_TOL:
            break
        for b in batches:
            m, ne, nb, nte = b.C.shape
            nx = b.gdof.shape[1]
            Cs = star_rows(b, nx).reshape(m * ne * nb, nx)
            te = batch_tractions(b, faces, t)
            res = -np.einsum("nrx,nx->nr", b.C.reshape(m * ne, nb, nte), te).ravel()
            cols = np.broadcast_to(b.gdof[:, None, :], (m, ne * nb, nx)).reshape(-1, nx)
            rows = np.broadcast_to(np.arange(m * ne * nb)[:, None], cols.shape)
            keep = (cols >= 0) & (Cs != 0)
            used, inv = np.unique(cols[keep], return_inverse=True)
            A = sp.csc_matrix((Cs[keep], (rows[keep], inv)), shape=(m * ne * nb, used.size))
            live = np.asarray(abs(A).sum(axis=1)).ravel() > 0
            x, _ = project_affine(A[live], res[live], np.zeros(used.size))
            t.reshape(-1)[used] += x
        after = float(element_imbalance(points, cells, maps, faces, t).max(initial=0.0))
    whole = after > REPAIR_TOL
    if whole:
        t = global_balance_projection(points, cells, maps, faces, t, free)
        after = float(element_imbalance(points, cells, maps, faces, t).max(initial=0.0))
    return t, before, after, whole


def global_balance_projection(points, cells, maps: ElementMaps, faces: Faces, t: np.ndarray,
                              free: np.ndarray) -> np.ndarray:
    """Least-norm correction of the free traction components ``free (F, d)`` onto every
    element's balance rows (:func:`~elastoplast.bounds.repair.project_affine`, one sparse
    factorisation of the rows' Gram matrix, of the element-adjacency pattern)."""
    n, d1 = cells.shape
    d = d1 - 1
    C = balance_matrices(points, cells, maps.facet_areas)  # (n, nb, nte)
    nb = C.shape[1]
    slot = np.where(faces.slot >= 0, faces.slot, 0)
    gd = ((faces.face[:, :, None] * d + slot)[..., None] * d + np.arange(d))  # (n, i, a, j)
    ok = (faces.slot >= 0)[..., None] & free[faces.face][:, :, None, :]
    sgn = np.where(ok, faces.sign[:, :, None, None], 0.0).reshape(n, -1)
    gd = gd.reshape(n, -1)
    vals = C * sgn[:, None, :]
    rows = np.broadcast_to(np.arange(n * nb).reshape(n, nb, 1), vals.shape)
    cols = np.broadcast_to(gd[:, None, :], vals.shape)
    keep = vals != 0
    used, inv = np.unique(cols[keep], return_inverse=True)
    A = sp.csc_matrix((vals[keep], (rows[keep], inv)), shape=(n * nb, used.size))
    te = element_tractions(faces, t).reshape(n, -1)
    res = -np.einsum("nrx,nx->nr", C, te).ravel()
    x, _ = project_affine(A, res, np.zeros(used.size))
    t = t.copy()
    t.reshape(-1)[used] += x
    return t
