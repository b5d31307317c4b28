"""One result type for every method, built from a candidate by :func:`make_solution`."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from elastoplast.certificate.kkt import KKTResiduals, certify, contact_forces, energy_norm_sq, gaps, work_density
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.locking import SMALL_STRAIN_LIMIT
from elastoplast.fem.material import return_mapping, von_mises
from elastoplast.certificate.kkt import real_number, shaped
from elastoplast.errors import short_repr

#: contact nodes whose force exceeds this share of the largest one count as active
ACTIVE_FORCE_SHARE = 1e-4
#: elements whose von Mises stress reaches this share of sigma_y + xi count as plastic
PLASTIC_SHARE = 1.0 - 1e-6


class Status(enum.Enum):
    CONVERGED = "converged"
    MAX_ITERATIONS = "max_iterations"
    TIME_LIMIT = "time_limit"
    DIVERGED = "diverged"
    INFEASIBLE = "infeasible"
    FAILED = "failed"


@dataclass(frozen=True)
class Solution:
    """A candidate solution of (2.1), its certificate and how it was obtained.

    ``sigma (n_el, k)`` Mandel stresses, ``xi (n_el)`` hardening stresses,
    ``u (n_nodes, d)`` nodal displacements, ``U`` the rigid body's displacement,
    ``contact_force``/``contact_pressure``/``active`` per contact node (in the
    order of ``Discretization.contact_nodes``), ``plastic`` per element.
    ``duality_gap`` is ``|value(S) + value(D)| / max(|value(S)|, |value(D)|)``
    evaluated at this candidate, NaN where the values are round-off (:func:`duality_gap`). ``timings`` in seconds; ``history`` one dict
    per iteration for iterative methods.
    """

    method: str
    status: Status
    sigma: np.ndarray
    xi: np.ndarray
    u: np.ndarray
    U: float
    contact_force: np.ndarray
    contact_pressure: np.ndarray
    active: np.ndarray
    plastic: np.ndarray
    kkt: KKTResiduals
    duality_gap: float
    value_S: float
    value_D: float
    iterations: int
    timings: dict[str, float]
    message: str = ""
    history: list[dict[str, Any]] = field(default_factory=list)

    @property
    def time_s(self) -> float:
        return float(self.timings.get("total", sum(self.timings.values())))

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED


#: the duality gap is reported only where the values exceed their round-off by this factor
GAP_ROUNDOFF_MARGIN = 1e3
#: the observed rounding of the values, in units of eps times their terms (about 10; see duality_gap)
GAP_ROUNDOFF_FACTOR = 16.0


def duality_gap(disc: Discretization, vS: float, vD: float, U: float, lam: np.ndarray) -> float:
    """``|vS + vD| / max(|vS|, |vD|)``, or NaN (printed ``n/a``) when the values are
    within ``GAP_ROUNDOFF_MARGIN`` of their own rounding. Both are differences of terms
    of size ``|F U|``, ``|psi| . |lam|`` and the energy; the contact forces carry a
    rounding of about eps times ``F`` at every node, which ``psi`` multiplies, so the
    values are known to ``R = GAP_ROUNDOFF_FACTOR * eps * (|F| sum|psi| + |F U| + |vS|)``.
    The energy scales with ``F**2`` and ``R`` with ``F``: at a force of 1e-9 the values
    are round-off and their gap (1e-2 to 1, for a U that is exactly linear) says nothing."""
    scale = max(abs(vS), abs(vD))
    rounding = GAP_ROUNDOFF_FACTOR * np.finfo(float).eps * (
        abs(disc.force) * float(np.abs(disc.psi).sum()) + abs(disc.force * U) + abs(vS)
        + float(np.abs(disc.psi) @ np.abs(lam)))
    if not scale > GAP_ROUNDOFF_MARGIN * rounding:
        return float("nan")
    return abs(vS + vD) / scale


def value_stress_form(disc: Discretization, sigma: np.ndarray, xi: np.ndarray, lam: np.ndarray) -> float:
    """Objective of (S): ``1/2 [sigma_hat, sigma_hat] + psi . lam``; on a step from a
    state, ``1/2 [sigma_hat - sigma_hat_n, sigma_hat - sigma_hat_n] + psi . lam`` (the
    step's ``psi`` holds the last displacement)."""
    if disc.state is not None:
        sigma, xi = sigma - disc.state.sigma, xi - disc.state.xi
    return 0.5 * energy_norm_sq(disc, sigma, xi) + float(disc.psi @ lam)


def value_displacement_form(disc: Discretization, u_free: np.ndarray, U: float) -> float:
    """Objective of (D) at ``(v, V) = (u, U)`` with the optimal ``(p, kappa)``.

    For fixed strains the minimum over plastic strains is reached by the return
    mapping, where ``eps - p = A sigma_R``, so the integrand is
    ``1/2 sigma_R A sigma_R + sigma_y kappa + 1/2 H kappa^2``
    (:func:`~elastoplast.certificate.kkt.work_density`, which also gives a step's).
    """
    sigma_R, _, kappa = return_mapping(disc.material, disc.strain(u_free), disc.state)
    return float(disc.volumes @ work_density(disc, sigma_R, kappa)) - disc.force * U


def contact_radius(disc: Discretization, active: np.ndarray, pressure: np.ndarray) -> float:
    """Radius (half-width in 2D) of the contact zone about the obstacle centre.

    The discrete contact edge lies between the outermost active node ``r_a``
    and the nearest inactive contact node beyond it ``r_i``. Near a smooth
    contact edge the pressure behaves like ``sqrt(b - r)``, so ``p^2`` is linear
    in ``r^2 - b^2 ~ 2b (r - b)``; for Hertz, ``p^2 = p0^2 (1 - r^2/b^2)``
    exactly, in 2D and 3D. A least-squares line through ``(r^2, p^2)`` over the
    active nodes in the outer half of the contact gives its zero ``b^2``,
    clipped to ``[r_a, r_i]``. Where that fit does not apply (fewer than three
    nodes, or a pressure not falling toward the edge) the midpoint of the
    bracket is used. Measured on six 2D Hertz meshes: within 1.6% of the
    formula, of either sign; a line in ``r`` (concave data) overshot by up to
    4.5%, the bracket midpoint by up to 13%. When the centre lies outside the
    contact zone (a large obstacle touching near the zone's edge), the result is
    the half-extent of the active set instead.
    """
    if not np.any(active):
        return 0.0
    xp = disc.mesh.points[disc.contact_nodes, :-1]
    centre = np.asarray(disc.problem.obstacle.center, dtype=float)
    if centre.size == xp.shape[1] and np.any((centre < xp.min(axis=0)) | (centre > xp.max(axis=0))):
        # a centre outside the zone (a large obstacle touching near its edge): no radius about it;
        # the half-extent of the active set instead
        return float(0.5 * np.ptp(xp[active], axis=0).max())
    r = disc.contact_radii()
    r_a = r[active].max()
    beyond = r[~active & (r > r_a)]
    if beyond.size == 0:
        return float(r_a)
    r_i = beyond.min()
    band = active & (r >= 0.5 * r_a) & np.isfinite(pressure)
    if np.unique(r[band]).size >= 3:
        slope, intercept = np.polyfit(r[band] ** 2, pressure[band] ** 2, 1)
        if slope < 0 and intercept > 0:
            return float(np.clip(np.sqrt(-intercept / slope), r_a, r_i))
    return float(0.5 * (r_a + r_i))


def make_solution(
    disc: Discretization,
    *,
    method: str,
    status: Status,
    sigma: np.ndarray,
    xi: np.ndarray,
    u_free: np.ndarray,
    U: float,
    contact_force: np.ndarray | None = None,
    iterations: int,
    timings: dict[str, float],
    message: str = "",
    history: list[dict[str, Any]] | None = None,
) -> Solution:
    """Certify a candidate and derive everything a user reads off a solution.

    ``contact_force`` defaults to the forces implied by ``sigma``.
    """
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    if not isinstance(status, Status):
        raise InputError("status", f"expected a Status (e.g. ep.Status.CONVERGED), got {short_repr(status)}")
    sigma = shaped(sigma, (disc.n_elements, disc.k), "sigma")
    xi = shaped(xi, (disc.n_elements,), "xi")
    u_free = shaped(u_free, (disc.n_free,), "u_free")
    U = real_number("U", U)
    u = disc.full_displacement(u_free)
    lam = contact_forces(disc, sigma) if contact_force is None else shaped(contact_force, (disc.n_contact,),
                                                                           "contact_force")
    kkt = certify(disc, sigma, xi, u, U, contact_force=lam)
    vS = value_stress_form(disc, sigma, xi, lam)
    vD = value_displacement_form(disc, u_free, U)
    gap = duality_gap(disc, vS, vD, U, lam)
    with np.errstate(divide="ignore", invalid="ignore"):
        pressure = np.where(disc.contact_area > 0, lam / disc.contact_area, np.nan)
    active = lam > ACTIVE_FORCE_SHARE * max(lam.max(initial=0.0), 0.0)
    plastic = von_mises(sigma) >= PLASTIC_SHARE * (disc.material.yield_stress + xi)
    finite = all(np.all(np.isfinite(a)) for a in (sigma, xi, u, lam)) and np.isfinite(U)
    if status is Status.CONVERGED and not (finite and np.isfinite(kkt.worst)):
        status = Status.FAILED
        message = f"{message}; the answer holds non-finite values" if message else "the answer holds non-finite values"
    if status is Status.CONVERGED:
        beyond = small_strain_note(disc, u_free)
        if beyond:  # said once, also when a method's message already says it (a plug-in judged again)
            status = Status.FAILED
            if beyond not in message:
                message = f"{message}; {beyond}" if message else beyond
    return Solution(
        method=method,
        status=status,
        sigma=sigma,
        xi=xi,
        u=u,
        U=float(U),
        contact_force=lam,
        contact_pressure=pressure,
        active=active,
        plastic=plastic,
        kkt=kkt,
        duality_gap=float(gap),
        value_S=vS,
        value_D=vD,
        iterations=int(iterations),
        timings=dict(timings),
        message=message,
        history=list(history or []),
    )


def solution_shapes(disc: Discretization) -> dict[str, tuple[int, ...]]:
    """The shape of each array of a :class:`Solution` of ``disc``."""
    n_el, n_c = disc.n_elements, disc.n_contact
    return {"u": (disc.mesh.n_nodes, disc.dim), "sigma": (n_el, disc.k), "xi": (n_el,), "plastic": (n_el,),
            "contact_force": (n_c,), "contact_pressure": (n_c,), "active": (n_c,)}


def check_solution(disc: Discretization, sol: Any, field: str, *, reads: tuple[str, ...] | None = None,
                   start: bool = False, advice: str = "") -> Solution:
    """``sol`` if it is a :class:`Solution` of ``disc``'s mesh, else an
    :class:`~elastoplast.errors.InputError` naming ``field``: the check of every
    function that takes a solution (a warm start, a summary, a bound's candidate).

    ``reads``: the arrays the caller uses (all of :func:`solution_shapes` by
    default; Newton's warm start reads ``u`` only, so a solution whose ``u`` was
    interpolated onto this mesh serves); ``start``: a solver starts from it, so
    those arrays and ``U`` must be finite (a diverged answer is no start);
    ``advice``: how to get a fitting one."""
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    expect(sol, Solution, field, "ep.solve(disc, method)")
    shapes = solution_shapes(disc)
    names = tuple(shapes) if reads is None else reads
    for name in names:
        shape = np.shape(getattr(sol, name))
        if shape != shapes[name]:
            raise InputError(field, f"is a Solution of another mesh: its {name} has shape {shape}, this "
                                    f"discretisation's {shapes[name]} ({disc.mesh.n_nodes} nodes, "
                                    f"{disc.n_elements} elements, {disc.n_contact} contact nodes)"
                                    + (f"; {advice}" if advice else ""))
    if start:
        for name in names + ("U",):
            value = getattr(sol, name)
            if not (np.asarray(value).dtype.kind in "iuf" and np.all(np.isfinite(value))):
                raise InputError(field, f"its {name} holds NaN or infinite values: no start (give a finite "
                                        "solution, or none to start from zero)")
    return sol


def largest_strain(disc: Discretization, u_free: np.ndarray) -> tuple[float, int]:
    """``(|eps|, element)``: the largest strain of a displacement, the Frobenius norm of
    each element's strain tensor (the Euclidean norm of its Mandel vector)."""
    norms = np.linalg.norm(disc.strain(np.asarray(u_free, dtype=float)), axis=1)
    i = int(np.argmax(norms)) if norms.size else 0
    return (float(norms[i]) if norms.size else 0.0), i


def small_strain_note(disc: Discretization, u_free: np.ndarray) -> str:
    """Why an answer is outside the small-strain model (its largest strain above
    :data:`~elastoplast.fem.locking.SMALL_STRAIN_LIMIT`), or ``""`` when it is not."""
    strain, element = largest_strain(disc, u_free)
    if not strain > SMALL_STRAIN_LIMIT:
        return ""
    return (f"the answer leaves the small-strain model: its strain reaches |eps| = {strain:.3g} (element {element}), "
            f"above {SMALL_STRAIN_LIMIT:g}, so it is no reference; the force needs more hardening than H = "
            f"{disc.material.hardening:g} to be carried within small strains (or lies above the limit load)")


def within_small_strains(disc: Discretization, sol: Solution) -> Solution:
    """``sol``, with a CONVERGED status turned FAILED (and the reason appended to its
    message) when its strains leave the small-strain model (:func:`small_strain_note`).
    :func:`make_solution` judges every candidate so; a method that settles on CONVERGED
    after building its answer (the conic methods, whose certificate overrides the
    interior point's own word) applies this to the answer it returns."""
    if sol.status is not Status.CONVERGED:
        return sol
    beyond = small_strain_note(disc, disc.free_displacement(sol.u))
    if not beyond:
        return sol
    if beyond in sol.message:  # said by make_solution before the method settled on CONVERGED again
        return replace(sol, status=Status.FAILED)
    return replace(sol, status=Status.FAILED, message=f"{sol.message}; {beyond}" if sol.message else beyond)


def summary(disc: Discretization, sol: Solution) -> dict[str, Any]:
    """The JSON summary of a solution (keys documented in docs/outputs.md)."""
    check_solution(disc, sol, "sol")
    vol = disc.volumes
    return {
        "method": sol.method,
        "status": sol.status.value,
        "message": sol.message,
        "U": sol.U,
        "force": disc.force,
        "iterations": sol.iterations,
        "time_s": sol.time_s,
        "timings": sol.timings,
        "kkt": sol.kkt.as_dict(),
        "kkt_worst": sol.kkt.worst,
        "duality_gap": sol.duality_gap,
        "value_S": sol.value_S,
        "value_D": sol.value_D,
        "max_contact_pressure": _max_finite(sol.contact_pressure),
        "contact_radius": contact_radius(disc, sol.active, sol.contact_pressure),
        "n_active_contact_nodes": int(sol.active.sum()),
        "plastic_volume_fraction": float(vol[sol.plastic].sum() / vol.sum()),
        "n_plastic_elements": int(sol.plastic.sum()),
        "max_von_mises": float(von_mises(sol.sigma).max()),
        "n_elements": disc.n_elements,
        "n_nodes": disc.mesh.n_nodes,
        "dim": disc.dim,
        "axisymmetric": disc.problem.axisymmetric,
        "gaps_min": float(gaps(disc, disc.free_displacement(sol.u), sol.U).min()),
    }


def _max_finite(values: np.ndarray) -> float:
    """The largest finite value (NaN when there is none)."""
    finite = values[np.isfinite(values)]
    return float(finite.max()) if finite.size else float("nan")
