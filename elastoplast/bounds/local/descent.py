"""Descent of the local field over every ring correction at once (docs/bounds.md, "a local field").

Ring sweeps (:mod:`elastoplast.bounds.local.sweeps`) minimise J one ring at a time. In plastic
zones that is a poor method: the rings' moves are strongly coupled there, and the sweeps
stall far above the optimum of the field's own space (on the quarter sphere at 162
tetrahedra, 512 sweeps stop at J = 79.8 while the optimum over the same self-equilibrated
corrections is below 35.5, itself below the global equilibrium program's 36.8; the
elastic case converges in 32 sweeps). The ring corrections together span every
self-equilibrated correction of the facet tractions (but for the contact zone's resultant
moments when free facets surround it: docs/bounds.md), so ``t = t0 + B y`` with ``B`` the
*frame* of all rings' bases (:class:`RingFrame`, redundant: an interior facet belongs to
several rings) parametrises the whole admissible set, and a quasi-Newton method on
``J(t0 + B y)`` (:func:`frame_descent`) moves all rings together. Every step is a sum of
ring corrections, so the field stays exactly admissible (up to round-off, which the ring
repair removes as after the sweeps); the contact pressure is kept ``>= 0`` by capping
each step, as the rings do, and by holding the pressures at zero that a step would lower."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from elastoplast.bounds.local.equilibrate import Faces, segment_ranges
from elastoplast.bounds.local.lift import ElementMaps
from elastoplast.bounds.local.rings import RingBatch
from elastoplast.bounds.local.state import SweepState
from elastoplast.bounds.local.sweeps import (LAM_MARGIN, in_slices, ring_corrections, ring_face_bases, ring_hessians,
                                             scaled_system)

#: L-BFGS pairs kept
MEMORY = 10
#: the descent stops once a step's predicted decrease of J is below this share of |J|
DESCENT_RTOL = 1e-6
#: with the upper bound known, the descent stops once its last DESCENT_WINDOW steps lowered J
#: by less than DESCENT_GAP_SHARE of the gap per step on average
DESCENT_WINDOW = 10
DESCENT_GAP_SHARE = 1e-3
#: the pressures held at zero in one step are held from the start of the next while still at zero;
#: the held set is found afresh every HOLD_STEPS steps (then a pressure the steps would raise is
#: released). Measured against finding it afresh at every step (a step then took about 6 rounds of
#: holding): quarter sphere at 1,080 tetrahedra, 300 steps, J 33.29 in 5.4 s against 34.16 in
#: 12.9 s (every 5 steps 33.38, 20: 33.19, never afresh: 36.22); default 3D problem at 5,184, 100
#: steps: J 128.09 in 14.1 s against 141.20 in 31.6 s
HOLD_STEPS = 10
#: Armijo's sufficient decrease
ARMIJO = 1e-4
#: a pressure at most this share of the largest counts as zero (its decrease is projected out)
ZERO_PRESSURE = 1e-6
#: the ridge added to the Gram matrix of the held pressures' rows (unit diagonal), for rows that depend on others
HELD_RCOND = 1e-10
#: at most this many projections in a row on the held pressures' rows, until their remainder is at most
#: HELD_REST of the largest unknown (the ridge leaves ~ HELD_RCOND / s^2 of a row's component each pass,
#: s the row's singular value: slow where rows of an adapted mesh's small facets nearly depend on others;
#: 20 passes left held pressures moving by 1e-7 on a cylinder mesh of 21,002 triangles, and the cap stopped the
#: descent at its first step: gap 4.8e-2, 1.9e-3 with 200 passes)
HELD_PASSES = 200
HELD_REST = 1e-15
#: a held pressure's change at most this share of the step's largest traction change is round-off (of the
#: pressure changes alone, it refused steps that moved the pressures little: a held pressure moving by 1e-17
#: stopped the descent after 3 steps on an adapted cylinder mesh of 15,446 triangles)
HELD_ROUNDOFF = 1e-12


class RingFrame:
    """The linear map ``y -> dt`` from every ring's unknowns (its facets' ``alpha`` then
    its ``q``, ring after ring, batch after batch) to the change of the facet tractions
    ``(F, d, d)``, and its adjoint."""

    def __init__(self, batches: list[RingBatch], points, faces: Faces, rings, d: int):
        self.parts = []
        self.n_faces = faces.nodes.shape[0]
        self.d = d
        self.where = []  # per part: its (ring, face position) slots sorted by facet, and those facets
        off = 0
        for b in batches:
            B = ring_face_bases(b, points, faces, rings, d)
            m, kf = b.F.shape
            nq = b.Nb.shape[2]
            na = B.shape[3] - nq
            self.parts.append((b, B, na, nq, off))
            order = np.argsort(b.F.ravel(), kind="stable")
            self.where.append((order, b.F.ravel()[order]))
            off += m * (kf * na + nq)
        self.size = off

    def apply(self, y: np.ndarray) -> np.ndarray:
        d = self.d
        dt = np.zeros((self.n_faces, d * d))
        for b, B, na, nq, off in self.parts:
            m, kf = b.F.shape
            dtau = ring_corrections(B, y[off: off + m * (kf * na + nq)].reshape(m, -1), nq)
            ok = b.F >= 0
            dt[b.F[ok]] += (b.s[..., None] * dtau)[ok]  # rings of one batch share no facet
        return dt.reshape(self.n_faces, d, d)

    def adjoint(self, g: np.ndarray) -> np.ndarray:
        """``B^T g`` of tractions ``g (F, d, d)``, or of a stack ``(K, F, d, d)`` (then ``(K, size)``)."""
        d = self.d
        stack = g.ndim == 4
        g2 = g.reshape(-1, self.n_faces, d * d)
        out = np.empty((g2.shape[0], self.size))
        for b, B, na, nq, off in self.parts:
            m, kf = b.F.shape
            ok = b.F >= 0
            gf = np.where(ok[..., None], b.s[..., None] * g2[:, np.where(ok, b.F, 0)], 0.0)  # (K, m, kf, dd)
            c = np.einsum("mfxc,kmfx->kmfc", B, gf)
            Y = out[:, off: off + m * (kf * na + nq)].reshape(-1, m, kf * na + nq)
            Y[..., :kf * na] = c[..., :na].reshape(-1, m, kf * na)
            Y[..., kf * na:] = c[..., na:].sum(axis=2)
        return out if stack else out[0]

    def unit_rows(self, f: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, sp.csr_matrix]:
        """``B^T e_i`` for the unit tractions ``e_i`` at facet ``f[i]``, entry ``x[i]`` (of its
        ``d d``), on the columns that any of them touches: ``(cols (c,), rows (k, c))``, the
        rows a CSR matrix (each row touches the few rings of one facet)."""
        pos, val, who = [], [], []
        for (b, B, na, nq, off), (order, facets) in zip(self.parts, self.where):
            kf = b.F.shape[1]
            r = kf * na + nq
            lo, hi = np.searchsorted(facets, f, "left"), np.searchsorted(facets, f, "right")
            i = np.repeat(np.arange(f.size), hi - lo)  # each occurrence of each f[i] in this part
            if i.size == 0:
                continue
            ring, fp = np.divmod(order[np.repeat(lo, hi - lo) + segment_ranges(hi - lo)], kf)
            v = b.s[ring, fp][:, None] * B[ring, fp, x[i], :]  # (h, na + nq)
            base = off + ring * r
            cols = np.concatenate([base[:, None] + fp[:, None] * na + np.arange(na),
                                   base[:, None] + kf * na + np.arange(nq)], axis=1)
            pos.append(cols.ravel())
            val.append(v.ravel())
            who.append(np.repeat(i, na + nq))
        if not pos:
            return np.zeros(0, dtype=np.int64), sp.csr_matrix((f.size, 0))
        pos, val, who = np.concatenate(pos), np.concatenate(val), np.concatenate(who)
        cols, at = np.unique(pos, return_inverse=True)
        # no entry twice: a facet is in one ring of a batch at most, and batches have their own columns
        return cols, sp.csr_matrix((val, (who, at)), shape=(f.size, cols.size))


class RingPreconditioner:
    """``v -> sum_r H_r^-1 v_r``: each ring's Hessian in its unknowns (:func:`~elastoplast.bounds.local.sweeps.ring_hessians`),
    Jacobi-scaled with a relative ridge as the sweeps solve it, inverted once at ``t``
    (an additive Schwarz preconditioner of the rings)."""

    def __init__(self, frame: RingFrame, points, maps: ElementMaps, faces: Faces, rings, t, volumes,
                 state: SweepState):
        self.blocks = []
        for b, B, na, nq, off in frame.parts:
            Hr = ring_hessians(b, points, maps, faces, rings, t, volumes, state)
            ds, Hs, dead = scaled_system(Hr)
            self.blocks.append((off, Hr.shape[0], Hr.shape[1], np.where(dead, 0.0, ds), np.linalg.inv(Hs)))

    def __call__(self, v: np.ndarray) -> np.ndarray:
        out = np.empty_like(v)
        for off, m, r, ds, Hinv in self.blocks:
            x = v[off: off + m * r].reshape(m, r) * ds
            out[off: off + m * r] = (np.matmul(Hinv, x[..., None])[..., 0] * ds).ravel()
        return out


def field_energy(maps: ElementMaps, faces: Faces, t: np.ndarray, volumes: np.ndarray, state: SweepState,
                 gradient: bool = True):
    """``(J, dJ/dt)`` of the facet tractions ``t (F, d, d)``: the lifted field's J (elements
    and the obstacle term ``sum psi lam`` of the Γ0 facets) and its gradient (or None), element
    by element in compiled loops (:func:`~elastoplast.bounds.local.kernel.field_energy_kernel`,
    slices of the elements in threads), into ``state``'s per-element buffers."""
    from elastoplast.bounds.local.kernel import add_element_gradients, field_energy_kernel

    n, d = maps.J.shape[:2]
    args = [t, faces.face, faces.slot, state.sign, maps.Jinv, state.scale, state.ops.Lfull,
            state.TP, state.base, volumes, state.A, state.M, state.sy, state.H, state.Dv,
            gradient, state.J_el, state.g_el]
    in_slices(field_energy_kernel, n, [np.require(a, requirements=("C", "W")) if isinstance(a, np.ndarray) else a
                                       for a in args], least=1024)
    c = state.contact
    J = float(state.J_el.sum()) + float((state.psi[c] * t[c, :, d - 1]).sum())
    if not gradient:
        return J, None
    g = np.zeros_like(t)
    add_element_gradients(state.g_el, faces.face, faces.slot, state.sign, g)
    g[c, :, d - 1] += state.psi[c]
    return J, g


def pressure_cap(t: np.ndarray, dt: np.ndarray, contact: np.ndarray, held: np.ndarray) -> float:
    """The largest step along ``dt`` (at most 1) that keeps the Γ0 pressures ``>= 0`` (short
    by :data:`~elastoplast.bounds.local.sweeps.LAM_MARGIN`), the ``held`` ones (:func:`pressure_projection`: they move by round-off) aside."""
    d = t.shape[2]
    lam, dlam = t[contact, :, d - 1], dt[contact, :, d - 1]
    down = dlam < 0
    roundoff = np.zeros_like(down)
    roundoff[held[:, 0], held[:, 1]] = True
    down &= ~(roundoff & (dlam >= -HELD_ROUNDOFF * np.abs(dt).max(initial=0.0)))
    if not down.any():
        return 1.0
    return float(min(1.0, (1.0 - LAM_MARGIN) * np.min(np.maximum(lam[down], 0.0) / -dlam[down])))


def at_zero(t: np.ndarray, contact: np.ndarray) -> np.ndarray:
    """``(n_cf, d)``: the Γ0 pressures (facet, vertex) that count as zero (at most
    :data:`ZERO_PRESSURE` of the largest)."""
    lam = t[contact, :, t.shape[2] - 1]
    return lam <= ZERO_PRESSURE * max(lam.max(initial=0.0), 1e-300)


def zero_pressures(t: np.ndarray, dt: np.ndarray, contact: np.ndarray, held: np.ndarray) -> np.ndarray:
    """``(k, 2)``: the (Γ0 facet, vertex) pairs not in ``held`` whose pressure is zero
    (:func:`at_zero`) and that ``dt`` lowers."""
    hit = at_zero(t, contact) & (dt[contact, :, t.shape[2] - 1] < 0)
    hit[held[:, 0], held[:, 1]] = False
    return np.argwhere(hit)


def still_zero(t: np.ndarray, pairs: np.ndarray, contact: np.ndarray) -> np.ndarray:
    """The (Γ0 facet, vertex) ``pairs`` whose pressure is still zero (:func:`at_zero`)."""
    return pairs[at_zero(t, contact)[pairs[:, 0], pairs[:, 1]]]


def pressure_projection(frame: RingFrame, t: np.ndarray, held: np.ndarray, contact: np.ndarray):
    """The orthogonal projection (in the ring unknowns) onto the moves that leave the
    pressures ``held`` ((Γ0 facet, vertex) pairs) alone: ``y - C^T (C C^T)^-1 C y`` with
    ``C`` the rows ``B^T e`` of the held pressures (normalised), on the few ring unknowns
    they touch. ``C`` is sparse (a row touches the rings of one facet), and so is ``C C^T``:
    it is factored sparse, with the relative ridge :data:`HELD_RCOND` for rows that depend
    on others (a dense orthonormal basis of the rows took half of a descent step at 98,304
    tetrahedra, about a thousand rows held)."""
    d = t.shape[2]
    cf = np.flatnonzero(contact)
    cols, C = frame.unit_rows(cf[held[:, 0]], held[:, 1] * d + d - 1)
    nrm = np.sqrt(np.asarray(C.multiply(C).sum(axis=1)).ravel())
    keep = nrm > 0  # a pressure no ring moves stays anyway
    C = (sp.diags(1.0 / nrm[keep]) @ C[keep]).tocsr()
    gram = spla.splu((C @ C.T + HELD_RCOND * sp.identity(C.shape[0])).tocsc())

    def proj(y):
        y = y.copy()
        for _ in range(HELD_PASSES):  # again on the remainder, until the held pressures move by round-off only
            y[cols] -= C.T @ gram.solve(C @ y[cols])
            rest = np.abs(C @ y[cols]).max(initial=0.0)
            if rest <= HELD_REST * np.abs(y[cols]).max(initial=0.0):
                break
        return y

    return proj


def lbfgs_direction(gy: np.ndarray, S: list, Y: list, H0, proj=None, gamma: float = 1.0) -> np.ndarray:
    """``-P H P gy``: L-BFGS's two loops (initial inverse Hessian ``gamma H0``, ``H0`` a
    callable: :func:`preconditioner_scale`) between the projections ``proj`` (P, or none)."""
    q = -(gy if proj is None else proj(gy))
    hist = []
    for s, yv in zip(reversed(S), reversed(Y)):
        rho = 1.0 / float(yv @ s)
        a = rho * float(s @ q)
        q = q - a * yv
        hist.append((a, rho))
    q = H0(q) * gamma
    for (s, yv), (a, rho) in zip(zip(S, Y), reversed(hist)):
        q = q + s * (a - rho * float(yv @ q))
    return q if proj is None else proj(q)


def preconditioner_scale(S: list, Y: list, H0) -> float:
    """The scale of the initial inverse Hessian ``H0`` measured by the last pair, ``s^T y / y^T H0 y``
    (the rings overlap: their sum over-steps); 1 without pairs."""
    return float(S[-1] @ Y[-1]) / float(Y[-1] @ H0(Y[-1])) if S else 1.0


def frame_descent(points, maps: ElementMaps, faces: Faces, rings, t: np.ndarray, volumes: np.ndarray, state: SweepState,
                  frame: RingFrame, iterations: int, progress=None, upper: float | None = None) -> tuple[np.ndarray, int]:
    """At most ``iterations`` L-BFGS steps on ``J(t + B y)`` (module docstring) with the
    rings' Hessians as the initial inverse (:class:`RingPreconditioner`, rebuilt when the
    memory is dropped), each step kept only where it lowers J enough (Armijo), capped so
    that the Γ0 pressures stay ``>= 0`` and with the pressures at zero that it would lower
    held (:func:`pressure_projection`; those of one step, and those the cap brought to
    zero in it, held from the start of the next while at zero, the set found afresh every
    :data:`HOLD_STEPS` steps); stops early once the predicted decrease is
    negligible (:data:`DESCENT_RTOL`), or, given the ``upper`` bound of the same problem
    (``Pi``; the gap is ``upper + J``), once the last :data:`DESCENT_WINDOW` steps lowered J
    by less than :data:`DESCENT_GAP_SHARE` of the gap each on average. Returns the new
    tractions and the steps taken; ``progress(i)`` is called after step i."""
    J, g = field_energy(maps, faces, t, volumes, state)
    gy = frame.adjoint(g)
    S, Y = [], []
    taken = 0
    history = [J]
    held = np.zeros((0, 2), dtype=np.int64)  # the (Γ0 facet, vertex) pairs held in the last step
    if upper is not None and not np.isfinite(upper):
        upper = None  # no gap to measure the gains against
    for it in range(iterations):
        if not S:  # (again) the rings' Hessians at this field
            H0 = RingPreconditioner(frame, points, maps, faces, rings, t, volumes, state)
        stuck = still_zero(t, held, state.contact) if it % HOLD_STEPS else held[:0]
        proj = pressure_projection(frame, t, stuck, state.contact) if stuck.size else None
        gamma = preconditioner_scale(S, Y, H0)
        while True:  # the pressures at zero that the step would lower are held (projected out), until none is left
            q = lbfgs_direction(gy, S, Y, H0, proj, gamma)
            dt = frame.apply(q)
            more = zero_pressures(t, dt, state.contact, stuck)
            if more.shape[0] == 0:
                break
            stuck = np.concatenate([stuck, more])
            proj = pressure_projection(frame, t, stuck, state.contact)
        held = stuck
        slope = float(gy @ q)
        if -slope <= DESCENT_RTOL * abs(J):  # the step's predicted decrease (about -slope / 2) is negligible
            break
        if not slope < 0:
            if not S:
                break
            S, Y = [], []
            continue
        alpha = pressure_cap(t, dt, state.contact, stuck)
        while alpha > 1e-12:
            Jn, gn = field_energy(maps, faces, t + alpha * dt, volumes, state)
            if Jn <= J + ARMIJO * alpha * slope:
                break
            # the minimiser of the quadratic through J, the slope and Jn, kept within [0.1, 0.5] alpha
            curv = Jn - J - slope * alpha
            alpha = float(np.clip(-slope * alpha * alpha / (2.0 * curv), 0.1 * alpha, 0.5 * alpha)) if curv > 0 \
                else 0.5 * alpha
        else:
            break
        gyn = frame.adjoint(gn)
        s, yv = alpha * q, gyn - gy
        if float(s @ yv) > 0:
            S.append(s)
            Y.append(yv)
            S, Y = S[-MEMORY:], Y[-MEMORY:]
        new = t + alpha * dt
        if stuck.size:  # a held pressure keeps its value exactly (>= 0); its round-off imbalance goes to the repair
            at = (np.flatnonzero(state.contact)[stuck[:, 0]], stuck[:, 1], t.shape[2] - 1)
            new[at] = t[at]
        t = new
        # the pressures this step brought to zero (the cap) are held from the next step on, like those held in it
        held = np.concatenate([stuck, zero_pressures(t, dt, state.contact, stuck)])
        J, g, gy = Jn, gn, gyn
        taken += 1
        history.append(J)
        if progress is not None:
            progress(it + 1)
        if upper is not None and taken >= DESCENT_WINDOW and \
                history[-1 - DESCENT_WINDOW] - J < DESCENT_WINDOW * DESCENT_GAP_SHARE * (upper + J):
            break  # what the steps still gain is small against the gap
    return t, taken
