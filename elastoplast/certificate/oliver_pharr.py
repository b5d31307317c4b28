"""Oliver-Pharr analysis of an indentation's first unloading (docs/indentation.md).

From the loading path's points (h = U, the indenter's displacement, and F the whole
indenter force), the first unloading is the run of points after the first peak along
which F falls. Its top is fitted with Oliver and Pharr's power law

    F = alpha (h - h_f)^m

by least squares over the unloading points with F >= ``FIT_SHARE`` F_max (the peak
and the first unloading point always included; at least three points, else the two topmost points' secant stands for the
slope, said in ``fit``). Then

    S   = dF/dh at h_max = m alpha (h_max - h_f)^(m - 1)
    h_c = h_max - eps F_max / S            (eps = 0.75, a paraboloid's)
    A   = A(h_c): 2 pi R h_c (paraboloid), pi (2 R h_c - h_c^2) (sphere),
          pi tan^2(theta) h_c^2 (cone of half-angle theta)
    H   = F_max / A,   E_r = sqrt(pi) S / (2 beta sqrt(A))  (beta = 1)

and E_r is set beside E* = E / (1 - nu^2) (a rigid indenter: E_r = E*).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from elastoplast.errors import InputError

#: the unloading points fitted: those with F at least this share of F_max
FIT_SHARE = 0.5
#: Oliver and Pharr's geometry constant of a paraboloid of revolution
EPSILON = 0.75
#: the correction factor of E_r (1 for a body of revolution)
BETA = 1.0
SHAPES = ("paraboloid", "sphere", "cone")


def projected_area(shape: str, h_c: float, *, radius: float | None = None, half_angle: float | None = None) -> float:
    """The indenter's cross-section at the contact depth ``h_c`` (``half_angle`` in degrees)."""
    if shape == "paraboloid":
        return 2.0 * math.pi * radius * h_c
    if shape == "sphere":
        return math.pi * (2.0 * radius * h_c - h_c * h_c)
    if shape == "cone":
        return math.pi * math.tan(math.radians(half_angle)) ** 2 * h_c * h_c
    raise InputError("obstacle.shape", f"Oliver-Pharr needs one of {list(SHAPES)}, got {shape!r}")


def first_unloading(forces: Sequence[float]) -> tuple[int, int] | None:
    """``(peak, end)`` indices of the first unloading: the first point after which F
    falls, and the last point of that falling run; None when F never falls."""
    F = np.asarray(forces, dtype=float)
    falls = np.flatnonzero(F[1:] < F[:-1])
    if falls.size == 0:
        return None
    peak = int(falls[0])
    end = peak + 1
    while end + 1 < F.size and F[end + 1] < F[end]:
        end += 1
    return peak, end


def fit_unloading(h: np.ndarray, F: np.ndarray) -> dict[str, Any]:
    """The power law's fit to unloading points (h, F), the peak first: ``S`` and the
    parameters ``alpha``, ``m``, ``h_f`` (None for the secant), and ``fit``."""
    from scipy.optimize import least_squares

    keep = F >= FIT_SHARE * F[0]
    keep[:2] = True  # the peak and the first unloading point at least
    h, F = h[keep], F[keep]
    if h.size < 3 or np.ptp(h) == 0.0:
        S = (F[0] - F[1]) / (h[0] - h[1])
        return {"S": float(S), "alpha": None, "m": None, "h_f": None, "fit": "secant of the two topmost points",
                "n_fit": int(h.size)}
    secant = (F[0] - F[-1]) / (h[0] - h[-1])
    m0 = 1.5
    h_f0 = h[0] - m0 * F[0] / secant  # the power law with m = 1.5 through the peak with the secant's slope
    scale_h = max(abs(h[0] - h_f0), np.ptp(h))

    def residual(p):
        log_alpha, m, h_f = p
        gap = np.maximum(h - h_f, 1e-300)
        return np.exp(log_alpha + m * np.log(gap)) / F[0] - F / F[0]

    start = [math.log(F[0]) - m0 * math.log(h[0] - h_f0), m0, h_f0]
    upper = [np.inf, 10.0, h.min() - 1e-12 * scale_h]
    start[2] = min(start[2], upper[2] - 1e-6 * scale_h)
    fit = least_squares(residual, start, bounds=([-np.inf, 1.0, -np.inf], upper), x_scale=[1.0, 1.0, scale_h],
                        xtol=1e-15, ftol=1e-15, gtol=1e-15)
    log_alpha, m, h_f = fit.x
    alpha = math.exp(log_alpha)
    S = m * alpha * (h[0] - h_f) ** (m - 1.0)
    return {"S": float(S), "alpha": alpha, "m": float(m), "h_f": float(h_f),
            "fit": f"F = alpha (h - h_f)^m, least squares over the {h.size} unloading points with F >= "
                   f"{FIT_SHARE:g} F_max", "n_fit": int(h.size),
            "fit_residual": float(np.max(np.abs(fit.fun)))}


def oliver_pharr(depths: Sequence[float], forces: Sequence[float], *, shape: str, E: float, nu: float,
                 radius: float | None = None, half_angle: float | None = None) -> dict[str, Any] | None:
    """The Oliver-Pharr figures of the first unloading (module docstring); None when
    the path never unloads. ``depths`` and ``forces``: the path's points in order."""
    h = np.asarray(depths, dtype=float)
    F = np.asarray(forces, dtype=float)
    if h.shape != F.shape or h.ndim != 1:
        raise InputError("depths", f"depths and forces must be two lists of one length, got {h.shape} and {F.shape}")
    if shape not in SHAPES:
        raise InputError("obstacle.shape", f"Oliver-Pharr needs one of {list(SHAPES)}, got {shape!r}")
    span = first_unloading(F)
    if span is None:
        return None
    peak, end = span
    h_max, F_max = float(h[peak]), float(F[peak])
    fit = fit_unloading(h[peak:end + 1], F[peak:end + 1])
    S = fit["S"]
    h_c = h_max - EPSILON * F_max / S
    out = {"step_peak": peak, "h_max": h_max, "F_max": F_max, **fit, "epsilon": EPSILON, "beta": BETA, "h_c": h_c,
           "A": float("nan"), "hardness": float("nan"), "E_r": float("nan"), "E_star": E / (1.0 - nu * nu)}
    if h_c > 0:
        A = projected_area(shape, h_c, radius=radius, half_angle=half_angle)
        out.update(A=A, hardness=F_max / A, E_r=math.sqrt(math.pi) * S / (2.0 * BETA * math.sqrt(A)))
    return out
