"""Outside reference values (docs/validation.md), as plain functions.

Units are whatever the caller uses consistently (here N, mm, MPa). Plane-strain
forces are per unit length.
"""

from __future__ import annotations

import math


def effective_modulus(E: float, nu: float) -> float:
    """``E* = E / (1 - nu^2)`` for a rigid indenter on an elastic body."""
    return E / (1.0 - nu * nu)


def hertz_sphere(F: float, R: float, E: float, nu: float) -> dict[str, float]:
    """Sphere on a half-space: contact radius ``a``, peak pressure ``p0``, approach ``delta``."""
    a = (3.0 * F * R / (4.0 * effective_modulus(E, nu))) ** (1.0 / 3.0)
    return {"a": a, "p0": 3.0 * F / (2.0 * math.pi * a * a), "delta": a * a / R}


def hertz_cylinder(F: float, R: float, E: float, nu: float) -> dict[str, float]:
    """Cylinder on a half-space in plane strain (F per unit length): half-width ``b``, ``p0``."""
    b = math.sqrt(4.0 * F * R / (math.pi * effective_modulus(E, nu)))
    return {"b": b, "p0": 2.0 * F / (math.pi * b)}


def sphere_force_for_p0(p0: float, R: float, E: float, nu: float) -> float:
    """Inverse of :func:`hertz_sphere`: ``F = pi^3 R^2 p0^3 / (6 E*^2)``."""
    return math.pi**3 * R * R * p0**3 / (6.0 * effective_modulus(E, nu) ** 2)


def cylinder_force_for_p0(p0: float, R: float, E: float, nu: float) -> float:
    """Inverse of :func:`hertz_cylinder`: ``F = pi R p0^2 / E*``."""
    return math.pi * R * p0 * p0 / effective_modulus(E, nu)


def green_first_yield_sphere(nu: float) -> dict[str, float]:
    """Green (2005) fit: ``p0 / sigma_y`` at first von Mises yield and its depth ``z / a``."""
    return {"p0_over_sy": 1.30075 + 0.87825 * nu + 0.54373 * nu * nu, "depth_over_a": 0.38167 + 0.33136 * nu}


def green_first_yield_cylinder(nu: float) -> dict[str, float]:
    """Green (2005) fit, plane strain: ``p0 / sigma_y`` at first yield and ``z / b``."""
    return {"p0_over_sy": 1.164 + 2.975 * nu - 2.906 * nu * nu, "depth_over_b": 0.223 + 2.321 * nu - 2.397 * nu * nu}


def prandtl_pressure(yield_stress: float) -> float:
    """Prandtl's limit pressure of a rigid flat punch, von Mises: ``(2 + pi) sigma_y / sqrt(3)``."""
    return (2.0 + math.pi) * yield_stress / math.sqrt(3.0)
