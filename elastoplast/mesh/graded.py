"""Graded meshes for indentation (gmsh): fine at the contact zone, coarse far away.

The 2D body is the rectangle ``[0, W] x [0, H]`` (the meridian half-plane for an
axisymmetric model, or the symmetric half of a plane-strain block); the 3D body is the
quarter block ``[0, W] x [0, W] x [0, H]``. The indenter's axis is ``x = 0`` (2D) or
``x = y = 0`` (3D), the contact plane ``x_d = 0``. The bottom is split exactly at the
contact zone: a segment ``[0, c]`` (2D) or a quarter disc of radius ``c`` (3D) forms the
``contact`` group, the rest of the bottom is ``bottom``. The element size is
``h_contact`` within ``c`` of the axis's foot and grows linearly with the distance from
the contact zone, at most by ``growth`` per unit length, up to ``h_far``.

Groups: ``xmin`` (the axis or symmetry plane x = 0), ``xmax``, in 3D ``ymin`` (the
symmetry plane y = 0) and ``ymax``, ``top``, ``bottom`` and ``contact``.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from elastoplast.errors import InputError, finite_float, short_repr
from elastoplast.mesh.base import Mesh, finite_list
from elastoplast.mesh.topology import boundary_facets

#: the element size grows by at most this much per unit distance from the contact zone
GROWTH = 0.3
#: the most elements a graded generator may make (a guard against a tiny h_contact)
MAX_ELEMENTS = 5_000_000


def symmetry_planes(dim: int) -> dict[str, list[str]]:
    """The graded block's symmetry planes by the component they fix: ``x`` on ``xmin``
    (the axis in 2D), and in 3D ``y`` on ``ymin``."""
    return {"x": ["xmin"], "y": ["ymin"]} if dim == 3 else {"x": ["xmin"]}


def check_centre_on_axis(center: Sequence[float], field: str = "obstacle.center") -> None:
    """The graded block with its default boundary (:func:`symmetry_planes`) is the half
    (quarter) of a body symmetric about the indenter's axis x = 0 (y = 0): an obstacle
    centred elsewhere would be mirrored by those planes into another problem than the one
    given (it was solved so, silently). Refused naming ``field``."""
    if any(float(c) != 0.0 for c in center):
        raise InputError(field, f"is {list(center)}: the graded block with its default boundary is the symmetric half "
                                "(3D: quarter) about the indenter's axis x = 0 (y = 0), so the obstacle is centred on "
                                "it (leave center out), or give a [boundary] table for another model")


def check_graded_arguments(size: Any, contact_radius: Any, h_contact: Any, h_far: Any) -> tuple:
    """``(size, contact_radius, h_contact, h_far)`` checked: each refusal an
    :class:`InputError` naming ``mesh.<argument>``."""
    size = finite_list(size, (2, 3), "mesh.size")
    if min(size) <= 0:
        raise InputError("mesh.size", f"positive lengths are required, got {short_repr(size)}")
    if len(size) == 3 and size[0] != size[1]:
        raise InputError("mesh.size", f"the 3D quarter block is square in x and y: got {size[0]} and {size[1]}")
    values = []
    for name, val in (("contact_radius", contact_radius), ("h_contact", h_contact), ("h_far", h_far)):
        v = finite_float(val)
        if v is None or not v > 0:
            raise InputError(f"mesh.{name}", f"must be a finite number > 0, got {short_repr(val)}")
        values.append(v)
    radius, hc, hf = values
    if radius >= size[0]:
        raise InputError("mesh.contact_radius", f"{radius} must be below the block's width {size[0]}")
    if hc > radius:
        raise InputError("mesh.h_contact", f"{hc} exceeds contact_radius {radius}: the contact zone would hold no "
                                           "element")
    if hf < hc:
        raise InputError("mesh.h_far", f"{hf} must be >= h_contact {hc}")
    if hf > min(size):
        raise InputError("mesh.h_far", f"{hf} exceeds the block's smallest side {min(size)}")
    dim = len(size)
    # a coarse count: the contact zone at h_contact (a disc of radius 2c) plus the rest at the mean size
    estimate = (2.0 * radius / hc) ** dim + np.prod(size) / ((hc + hf) / 2.0) ** dim
    estimate *= 2.0 if dim == 2 else 6.0
    if estimate > MAX_ELEMENTS:
        raise InputError("mesh.h_contact", f"about {estimate:.3g} elements expected (more than {MAX_ELEMENTS}): "
                                           "raise h_contact or h_far")
    return size, radius, hc, hf


def graded_mesh(size: Sequence[float], contact_radius: float, h_contact: float, h_far: float,
                growth: float = GROWTH) -> Mesh:
    """The graded indentation mesh (module docstring): ``size = [W, H]`` (2D) or
    ``[W, W, H]`` (3D). Needs gmsh (``pip install elastoplast[mesh]``)."""
    size, radius, hc, hf = check_graded_arguments(size, contact_radius, h_contact, h_far)
    try:
        import gmsh
    except ImportError as exc:  # an optional dependency
        raise InputError("mesh.generator", "the 'graded' generator needs gmsh: pip install 'elastoplast[mesh]'") from exc
    dim = len(size)
    initialized = gmsh.isInitialized()
    if not initialized:
        gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("elastoplast-graded")
        contact = _build_geometry(gmsh, size, radius)
        _size_field(gmsh, contact, dim, hc, hf, growth)
        gmsh.model.mesh.generate(dim)
        return _to_mesh(gmsh, size, radius, dim)
    finally:
        gmsh.model.remove()
        if not initialized:
            gmsh.finalize()


def _build_geometry(gmsh, size: list[float], radius: float) -> list[int]:
    """The body with its bottom split at the contact zone; returns the contact entities' tags."""
    occ = gmsh.model.occ
    if len(size) == 2:
        w, h = size
        corners = [occ.addPoint(x, y, 0.0) for x, y in ((0.0, 0.0), (radius, 0.0), (w, 0.0), (w, h), (0.0, h))]
        lines = [occ.addLine(corners[i], corners[(i + 1) % 5]) for i in range(5)]
        occ.addPlaneSurface([occ.addCurveLoop(lines)])
        occ.synchronize()
        dim_target = 1
    else:
        w, _, h = size
        box = occ.addBox(0.0, 0.0, 0.0, w, w, h)
        disk = occ.addDisk(0.0, 0.0, 0.0, radius, radius)
        rect = occ.addRectangle(0.0, 0.0, 0.0, w, w)
        quarter, _ = occ.intersect([(2, disk)], [(2, rect)])
        occ.fragment([(3, box)], quarter)
        occ.synchronize()
        dim_target = 2
    tol = 1e-3 * radius  # OCC pads bounding boxes; the next corner is at least W - c away
    found = gmsh.model.getEntitiesInBoundingBox(-tol, -tol, -tol, radius + tol, radius + tol if len(size) == 3 else tol,
                                                tol, dim_target)
    return [tag for _, tag in found]


def _size_field(gmsh, contact: list[int], dim: int, hc: float, hf: float, growth: float) -> None:
    """Size h_contact on the contact zone, growing linearly with the distance to h_far."""
    field = gmsh.model.mesh.field
    dist = field.add("Distance")
    field.setNumbers(dist, "CurvesList" if dim == 2 else "SurfacesList", contact)
    field.setNumber(dist, "Sampling", 100)
    thr = field.add("Threshold")
    field.setNumber(thr, "InField", dist)
    field.setNumber(thr, "SizeMin", hc)
    field.setNumber(thr, "SizeMax", hf)
    field.setNumber(thr, "DistMin", 0.0)
    field.setNumber(thr, "DistMax", (hf - hc) / growth)
    field.setAsBackgroundMesh(thr)
    for key in ("Mesh.MeshSizeExtendFromBoundary", "Mesh.MeshSizeFromPoints", "Mesh.MeshSizeFromCurvature"):
        gmsh.option.setNumber(key, 0)
    gmsh.option.setNumber("Mesh.Algorithm", 6)


def _to_mesh(gmsh, size: list[float], radius: float, dim: int) -> Mesh:
    """The gmsh model's simplices as a :class:`Mesh`, facet groups found by position."""
    tags, coords, _ = gmsh.model.mesh.getNodes()
    simplex = 2 if dim == 2 else 4
    _, nodes = gmsh.model.mesh.getElementsByType(simplex)
    cells_tags = np.asarray(nodes, dtype=np.int64).reshape(-1, dim + 1)
    used = np.unique(cells_tags)
    lookup = np.full(int(np.max(tags)) + 1, -1, dtype=np.int64)
    lookup[np.asarray(tags, dtype=np.int64)] = np.arange(len(tags))
    all_points = np.asarray(coords, dtype=float).reshape(-1, 3)[:, :dim]
    keep = lookup[used]
    renumber = np.full(len(tags), -1, dtype=np.int64)
    renumber[keep] = np.arange(len(keep))
    points = all_points[keep]
    cells = renumber[lookup[cells_tags]]
    X = points[cells]
    det = np.linalg.det(np.swapaxes(X[:, 1:] - X[:, :1], 1, 2))
    cells[det < 0, :2] = cells[det < 0, 1::-1]
    return Mesh(points=points, cells=cells, groups=_groups(points, cells, size, radius))


def _groups(points: np.ndarray, cells: np.ndarray, size: list[float], radius: float) -> dict[str, np.ndarray]:
    """The boundary facets named by the face they lie on (module docstring)."""
    dim = len(size)
    facets = boundary_facets(cells)
    fx = points[facets]
    tol = 1e-9 * max(size)
    on = lambda axis, val: np.all(np.abs(fx[:, :, axis] - val) < tol, axis=1)  # noqa: E731
    groups = {"xmin": on(0, 0.0), "xmax": on(0, size[0])}
    if dim == 3:
        groups["ymin"] = on(1, 0.0)
        groups["ymax"] = on(1, size[1])
    base = on(dim - 1, 0.0)
    inside = np.all(np.linalg.norm(fx[:, :, :-1], axis=2) <= radius * (1 + 1e-9) + tol, axis=1)
    groups["contact"] = base & inside
    groups["bottom"] = base & ~inside
    groups["top"] = on(dim - 1, size[-1])
    return {name: facets[mask] for name, mask in groups.items()}
