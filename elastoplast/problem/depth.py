"""Depth control's problem-file checks: a depth path's displacements, and the first
force the root search of :func:`~elastoplast.solvers.depth.solve_depth` tries."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from elastoplast.errors import InputError, short_repr
from elastoplast.fem.material import Material
from elastoplast.mesh.base import Mesh


def check_depths(depths: Any, field: str = "load.displacement_path") -> tuple[float, ...]:
    """The prescribed displacements of a depth path as floats, or an :class:`InputError`
    naming ``field``: a non-empty list of finite numbers, any sign and order (a depth
    at or above the unloaded gap is a lift-off, F = 0)."""
    if isinstance(depths, (str, bytes, Mapping)) or not isinstance(depths, Sequence) and not (
            isinstance(depths, np.ndarray) and depths.ndim == 1):
        raise InputError(field, f"must be a list of displacements, got {short_repr(depths)}")
    if len(depths) == 0:
        raise InputError(field, "is empty: give at least one displacement")
    out = []
    for i, d in enumerate(depths):
        if isinstance(d, (bool, np.bool_)) or not isinstance(d, (int, float, np.integer, np.floating)):
            raise InputError(field, f"entry {i + 1} must be a number, got {short_repr(d)}")
        if not np.isfinite(d):
            raise InputError(field, f"entry {i + 1} must be finite, got {d!r}")
        out.append(float(d))
    return tuple(out)


def depth_force_guess(material: Material, mesh: Mesh, depth: float, axisymmetric: bool = False) -> float:
    """A first force for the root search of depth control (never a result): E* |delta|
    times the geometric mean of |delta| and the mesh's width to the power d - 2 (a
    force per unit length in plane strain, a force in 3D and axisymmetric models, d = 3
    for those), with |delta| a millionth of the width when delta = 0."""
    e_star = material.E / (1.0 - material.nu ** 2)
    width = float(np.ptp(mesh.points[:, 0]))
    length = abs(depth) if depth != 0 else 1e-6 * width
    return e_star * length * float(np.sqrt(length * width)) ** ((3 if axisymmetric else mesh.dim) - 2)
