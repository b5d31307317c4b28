"""An answer computed anywhere, judged like every built-in method's.

When ``sigma``/``xi`` are absent the stresses are the return mapping of the strains of
``u``; the contact forces are those the stresses imply (``N r``, as
:func:`~elastoplast.certificate.solution.make_solution` takes them when a method gives
none); :func:`~elastoplast.certificate.kkt.certify` measures the eight residuals
(``dirichlet`` on ``u`` as given). It is certified when every residual is at most ``tol``
and its strains stay within the small-strain model (:func:`certify_answer`).
:func:`answer_bounds` adds the continuum upper bound of this displacement field
(:func:`~elastoplast.bounds.upper.upper_bound`), the lower bound of the equilibrium
element and their energy and U brackets. The answer is read by
:func:`~elastoplast.io.answers.read_answer`.
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any, Mapping

import numpy as np

from elastoplast.certificate.kkt import KKTResiduals, certify
from elastoplast.certificate.solution import Solution, Status, make_solution
from elastoplast.errors import InputError, expect, figure, short_repr
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import return_mapping
from elastoplast.io.answers import FIELD, NPZ_ARRAYS, check_shape, check_values
from elastoplast.options import SolverOptions

#: the method name the answer's Solution carries (summary.json's "method")
METHOD = "answer"
#: the largest stress scale (E |u| / shortest edge, |sigma|, |xi|) the certificate takes:
#: beyond it its squares and energies overflow floating point (no small-strain answer comes near)
MAX_MAGNITUDE = 1e100


def failed_residuals(kkt: KKTResiduals, tol: float) -> list[str]:
    """The residuals above ``tol`` (a NaN is never small)."""
    return [name for name, value in kkt.as_dict().items() if not value <= tol]


def certify_answer(disc: Discretization, answer: Mapping[str, Any], tol: float, seconds: float = 0.0) -> Solution:
    """The answer as a :class:`Solution` (method ``"answer"``), judged by the certificate:
    CONVERGED when every residual is at most ``tol`` and the strains stay small, FAILED
    otherwise (the message says why). Stresses absent: the return mapping of the strains
    of ``u``; contact forces: those the stresses imply. The residuals are those of ``u``
    as given (its fixed components included, which ``dirichlet`` judges).

    Refused (InputError naming ``ANSWER.<array>``, or ``disc``, ``tol``): an answer that
    is no mapping, arrays of the wrong shape, NaN or infinite values, and magnitudes
    that would overflow the certificate's arithmetic (:func:`check_magnitudes`)."""
    t0 = time.perf_counter()
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    expect(answer, Mapping, "answer", "read_answer(path, disc), or a dict with u and U")
    try:
        tol = SolverOptions.build({"tol": tol}).tol
    except InputError as exc:
        raise InputError("tol", exc.message) from None
    arrays = {}
    for name in NPZ_ARRAYS:
        value = answer.get(name)
        if value is None:
            if name in ("u", "U"):
                raise InputError(f"{FIELD}.{name}", "missing")
            continue
        arr = np.asarray(value)
        if arr.dtype.kind not in "iuf":
            raise InputError(f"{FIELD}.{name}", f"expected real numbers, got {short_repr(value)}")
        check_shape(name, arr.shape, disc)
        arrays[name] = check_values(name, arr)
    u, U = arrays["u"], float(arrays["U"].reshape(-1)[0])
    sigma, xi = arrays.get("sigma"), arrays.get("xi")
    if (sigma is None) != (xi is None):
        given, other = ("sigma", "xi") if xi is None else ("xi", "sigma")
        raise InputError(f"{FIELD}.{other}", f"missing ({given} is given: give both, or neither for the stresses of "
                                             "the return mapping of u)")
    check_magnitudes(disc, u, U, sigma, xi)
    with np.errstate(all="ignore"):
        u_free = disc.free_displacement(u)
        if sigma is None:
            sigma, xi, _ = return_mapping(disc.material, disc.strain(u_free))
        sol = make_solution(disc, method=METHOD, status=Status.CONVERGED, sigma=sigma, xi=xi, u_free=u_free, U=U,
                            iterations=0, timings={})
        kkt = certify(disc, sol.sigma, sol.xi, u, U, contact_force=sol.contact_force)
    above = failed_residuals(kkt, tol)
    reasons = [f"{', '.join(above)} above tol {tol:g} (worst {figure(kkt.worst, '.2e')})"] if above else []
    finite = all(np.all(np.isfinite(a)) for a in (sol.sigma, sol.xi, sol.contact_force)) and math.isfinite(kkt.worst)
    if not finite:  # the input is finite and below MAX_MAGNITUDE: the arithmetic overflowed all the same
        reasons = [f"the certificate overflowed (displacements up to {np.abs(u).max(initial=abs(U)):.3g}): not "
                   "certified"]
    elif sol.status is not Status.CONVERGED:  # make_solution's own verdict: strains beyond the small-strain model
        reasons.append(sol.message)
    status = Status.FAILED if reasons else Status.CONVERGED
    message = "; ".join(reasons) if reasons else (f"every KKT residual at most tol {tol:g} (worst "
                                                  f"{figure(kkt.worst, '.2e')})")
    timings = {"check": seconds + time.perf_counter() - t0}
    return replace(sol, u=u, kkt=kkt, status=status, message=message, timings=timings)


def check_magnitudes(disc: Discretization, u: np.ndarray, U: float, sigma: np.ndarray | None,
                     xi: np.ndarray | None) -> None:
    """Refuse finite values so large that the certificate's strains, stresses or energies
    overflow floating point: a stress scale (``E |u| / shortest edge``, ``|sigma|``,
    ``|xi|``) above :data:`MAX_MAGNITUDE`. Such an answer is no small-strain answer."""
    from elastoplast.mesh.base import shortest_edge

    points = disc.mesh.points
    h = shortest_edge(points, disc.mesh.cells)
    extent = float(np.max(points.max(axis=0) - points.min(axis=0)))
    E = float(disc.material.E)
    for name, value in (("u", float(np.abs(u).max(initial=0.0))), ("U", abs(U))):
        if value * E > MAX_MAGNITUDE * h:
            raise InputError(f"{FIELD}.{name}", f"values up to {value:.3g} overflow the strains (the mesh is "
                                                f"{extent:.3g} across, its shortest edge {h:.3g}, E = {E:g}): not "
                                                "displacements in the problem's units")
    for name, arr in (("sigma", sigma), ("xi", xi)):
        value = 0.0 if arr is None else float(np.abs(arr).max(initial=0.0))
        if value > MAX_MAGNITUDE:
            raise InputError(f"{FIELD}.{name}", f"values up to {value:.3g} overflow the certificate's energies (at "
                                                f"most {MAX_MAGNITUDE:.0e}; E = {E:g}, yield stress "
                                                f"{disc.material.yield_stress:g})")


#: ``check --bounds``'s lower bound: the global program (an answer's stresses need not balance to round-off)
GLOBAL = {"kind": "global"}


def answer_bounds(disc: Discretization, sol: Solution):
    """The energy and U brackets of the answer's displacement field (a
    :class:`~elastoplast.bounds.bracket.BoundsReport`), built from the same pieces as
    :func:`~elastoplast.references.certified.certified_bounds` with the upper bound of this
    field instead of a solve's: the field with its fixed components at zero (the
    ``dirichlet`` residual judges whether the answer had them so; the bound is that of
    the admissible field it implies)."""
    from elastoplast.bounds.bracket import BoundsReport, combine, lower_bound
    from elastoplast.references.certified import u_bracket_of
    from elastoplast.bounds.upper import upper_bound

    t0 = time.perf_counter()
    upper = upper_bound(disc, replace(sol, u=disc.full_displacement(disc.free_displacement(sol.u))))
    t1 = time.perf_counter()
    lower = lower_bound(disc, sol, GLOBAL)
    t2 = time.perf_counter()
    b = combine(upper, lower)
    U_lo, U_hi, delta, ok = u_bracket_of(disc, b, sol.U, GLOBAL)
    timings = {"upper": t1 - t0, "lower": t2 - t1, "bracket": time.perf_counter() - t2}
    return BoundsReport(bounds=b, upper=upper, lower=lower, U_lower=U_lo, U_upper=U_hi, delta=delta, timings=timings,
                        bracket_certified=ok)
