"""The ``[load]`` table's lists: a loading path's forces (:func:`check_forces`), a depth
path's displacements (:func:`check_depths`), read by one rule (:func:`number_list`);
and the first force the root search of :func:`~elastoplast.solvers.depth.solve_depth`
tries."""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from elastoplast.errors import InputError, finite_float, short_repr
from elastoplast.fem.material import Material
from elastoplast.mesh.base import Mesh


def number_list(values: Any, field: str, noun: str, one: str, kind: str) -> list[float]:
    """``values`` as finite floats, or an :class:`InputError` naming ``field``: a
    non-empty list (or 1D array) of numbers, each finite; ``noun`` ("forces > 0"),
    ``one`` ("force > 0") and ``kind`` ("a number > 0") word the refusals."""
    if isinstance(values, (str, bytes, Mapping)) or not isinstance(values, Sequence) and not (
            isinstance(values, np.ndarray) and values.ndim == 1):
        raise InputError(field, f"must be a list of {noun}, got {short_repr(values)}")
    if len(values) == 0:
        raise InputError(field, f"is empty: give at least one {one}")
    out = []
    for i, v in enumerate(values):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise InputError(field, f"entry {i + 1} must be {kind}, got {short_repr(v)}")
        value = finite_float(v)  # None for nan, inf and integers beyond the float range
        if value is None:
            raise InputError(field, f"entry {i + 1} must be a finite number, got {short_repr(v)}")
        out.append(value)
    return out


def check_forces(forces: Any, field: str = "load.path") -> tuple[float, ...]:
    """The forces of a loading path as floats, or an :class:`InputError` naming
    ``field``: a non-empty list of finite numbers > 0, in any order (loading,
    unloading, reloading). A force of 0 is refused: the body may then lift off the
    rigid body, and U is not determined (end an unloading at a small force)."""
    out = number_list(forces, field, "forces > 0", "force > 0", "a number > 0")
    for i, value in enumerate(out):
        if value <= 0.0:
            raise InputError(field, f"entry {i + 1} must be a force > 0, got {value:g} (at F = 0 the body may lift "
                                    "off and U is not determined; end an unloading at a small F)")
    return tuple(out)


def check_depths(depths: Any, field: str = "load.displacement_path") -> tuple[float, ...]:
    """The prescribed displacements of a depth path as floats, or an :class:`InputError`
    naming ``field``: a non-empty list of finite numbers, any sign and order (a depth
    at or above the unloaded gap is a lift-off, F = 0)."""
    return tuple(number_list(depths, field, "displacements", "displacement", "a number"))


def depth_force_guess(material: Material, mesh: Mesh, depth: float, axisymmetric: bool = False) -> float:
    """A first force for the root search of depth control (never a result): E* |delta|
    times the geometric mean of |delta| and the mesh's width to the power d - 2 (a
    force per unit length in plane strain, a force in 3D and axisymmetric models, d = 3
    for those), with |delta| at least a millionth of the width (a smaller guess, down to
    1e-300, would be refused as a load no solver can scale, naming ``load.force``, which
    the user did not give; the search narrows from there)."""
    e_star = material.E / (1.0 - material.nu ** 2)
    width = float(np.ptp(mesh.points[:, 0]))
    length = max(abs(depth), 1e-6 * width)
    return e_star * length * float(np.sqrt(length * width)) ** ((3 if axisymmetric else mesh.dim) - 2)
