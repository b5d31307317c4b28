"""Problem description: the Python API and the TOML format.

A :class:`Problem` is fully resolved: a mesh, a material, boundary groups, an
obstacle and a force, or a loading path (``[load] path = [F_1, F_2, ...]``: one
backward-Euler step of Prandtl-Reuss' law per force, docs/evolution.md).
:func:`load_problem` reads the TOML format of docs/problem-files.md;
:func:`problem_from_dict` takes the same structure as nested dicts. Every
complaint about the input is an :class:`InputError` naming the key.
"""

from __future__ import annotations

import os
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, Sequence

import numpy as np

from elastoplast.limits import as_path, read_bytes
from elastoplast.errors import InputError
from elastoplast.fem.material import Material
from elastoplast.mesh.base import Mesh, read_mesh, structured_mesh
from elastoplast.mesh.checks import check_axisymmetric
from elastoplast.mesh.graded import check_centre_on_axis, graded_mesh, symmetry_planes
from elastoplast.errors import finite_float, short_repr
from elastoplast.problem.load import check_depths, check_forces, depth_force_guess
from elastoplast.problem.expressions import SAFE_FUNCTIONS, compile_expression

AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Boundary:
    """Named facet groups: ``clamped`` (u = 0), ``contact`` (the zone Γ0), and
    ``fix_component[axis] -> groups`` fixing one component (symmetry planes)."""

    clamped: tuple[str, ...]
    contact: tuple[str, ...]
    fix_component: Mapping[int, tuple[str, ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "clamped", tuple(self.clamped))
        object.__setattr__(self, "contact", tuple(self.contact))
        object.__setattr__(
            self, "fix_component", MappingProxyType({int(k): tuple(v) for k, v in dict(self.fix_component).items()})
        )

    def __reduce__(self):
        # MappingProxyType cannot be pickled: pickle a plain dict, rebuilt read-only on load
        return (Boundary, (self.clamped, self.contact, dict(self.fix_component)))


MAX_PSI_OVER_SPAN = 1e6


def _check_psi(psi: np.ndarray, xp: np.ndarray, what: str, field: str, centre=None) -> np.ndarray:
    """The obstacle at the contact nodes must be finite, >= 0 (docs/math.md: the
    rigid body lies below x_d = 0 and touches the body where psi = 0), with a relief
    (max - min over the nodes) of at most ``MAX_PSI_OVER_SPAN`` times the zone's size
    (steeper, it touches one node and its values elsewhere only upset the solvers), and
    no farther than that below the zone (its lowest value at most that many times the
    size: beyond, the displacements are lost to the round-off of the gap U includes).
    A psi that does not reach 0 on the zone, within that distance, only shifts U by the
    gap, which is said in a warning: for a shape with a ``centre`` (psi = 0 there) when
    the centre lies outside the zone's bounding box, for a formula when its minimum at
    the nodes exceeds half its range over them."""
    if not np.all(np.isfinite(psi)):
        bad = np.flatnonzero(~np.isfinite(psi))[0]
        raise InputError(field, f"{what} is not finite at every contact node (e.g. {psi[bad]} at x' = "
                                f"{xp[bad].tolist()})")
    if psi.size == 0:
        return psi
    span = float(np.max(xp.max(axis=0) - xp.min(axis=0))) if xp.size else 0.0
    scale = max(span, float(np.abs(psi).max()))
    low, high = float(psi.min()), float(psi.max())
    if low < -1e-12 * scale:
        i = int(np.argmin(psi))
        raise InputError(field, f"{what} is negative at contact nodes (min {low:.4g} at x' = {xp[i].tolist()}): the "
                                "rigid body would start inside the body; psi >= 0, with 0 where it first touches")
    relief = high - low
    if relief > MAX_PSI_OVER_SPAN * span:
        i = int(np.argmax(psi))
        raise InputError(field, f"{what} rises to {high:.4g} at x' = {xp[i].tolist()}, {relief:.4g} above its lowest "
                                f"value, more than {MAX_PSI_OVER_SPAN:g} times the size {span:.4g} of the contact zone: "
                                "a surface this steep touches one node and its values elsewhere only upset the solvers")
    named = field if centre is None else field.rsplit(".", 1)[0] + ".center"
    if low > MAX_PSI_OVER_SPAN * span:
        i = int(np.argmin(psi))
        raise InputError(named, f"{what} lies {low:.4g} below the contact zone (its closest point, at x' = "
                                f"{xp[i].tolist()}), more than {MAX_PSI_OVER_SPAN:g} times the size {span:.4g} of the "
                                "zone: U would include that gap, and the displacements would be lost to its round-off; "
                                "move the obstacle up to the body (psi = 0 where it first touches)")
    if centre is not None:
        gap = bool(np.any((np.asarray(centre) < xp.min(axis=0)) | (np.asarray(centre) > xp.max(axis=0))))
    else:
        gap = low > 1e-12 * scale and low > 0.5 * (high - low)
    if gap:
        warnings.warn(f"{named}: the obstacle does not touch the body before loading (min psi = {low:.4g} > 0 at "
                      "the contact nodes): U includes this initial gap", stacklevel=3)
    return np.maximum(psi, 0.0)


@dataclass(frozen=True)
class Obstacle:
    """Rigid body surface ``x_d = -psi(x')`` (docs/math.md).

    ``shape``: ``sphere`` (3D, and the meridian profile of an axisymmetric model) /
    ``cylinder`` (2D): ``R - sqrt(R^2 - |x'-c|^2)``; ``paraboloid``: ``|x'-c|^2 / (2R)``;
    ``cone``: ``|x'-c| / tan(half_angle)`` (``half_angle`` in degrees, between the axis and
    the flank); ``flat``: 0; ``expression``: a formula in ``x`` (and ``y`` in 3D; ``r`` in
    an axisymmetric model).
    """

    shape: str
    dim: int
    radius: float | None = None
    center: tuple[float, ...] = ()
    expression: str | None = None
    half_angle: float | None = None
    axisymmetric: bool = False

    def __post_init__(self) -> None:  # make_obstacle's ranges, also for dataclasses.replace
        r, a = finite_float(self.radius), finite_float(self.half_angle)
        if self.shape in ("sphere", "cylinder", "paraboloid") and not (r is not None and r > 0):
            raise InputError("obstacle.radius", f"must be a finite number > 0, got {short_repr(self.radius)}")
        if self.shape == "cone" and not (a is not None and 0.0 < a < 90.0):
            raise InputError("obstacle.half_angle", f"must lie in (0, 90) degrees, got {short_repr(self.half_angle)}")

    def psi(self, xp: np.ndarray, field: str = "obstacle") -> np.ndarray:
        """Evaluate psi at in-plane points ``xp`` (n, d-1); refuses points outside its domain."""
        with np.errstate(all="ignore"):  # overflow to inf is refused by _check_psi
            r2 = np.sum((xp - np.asarray(self.center)) ** 2, axis=1)
            if self.shape in ("sphere", "cylinder"):
                R = self.radius
                if np.sqrt(r2.max(initial=0.0)) >= R:
                    raise InputError(
                        f"{field}.radius",
                        f"radius {R:g} is smaller than the contact zone (which reaches {np.sqrt(r2.max()):g} "
                        f"from the centre {list(self.center)})",
                    )
                # = R - sqrt(R^2 - r^2), without cancellation
                return _check_psi(r2 / (R + np.sqrt(R * R - r2)), xp, f"the {self.shape}", f"{field}.radius",
                                  self.center)
            if self.shape == "paraboloid":
                return _check_psi(r2 / (2.0 * self.radius), xp, "the paraboloid", f"{field}.radius", self.center)
            if self.shape == "cone":
                return _check_psi(np.sqrt(r2) / np.tan(np.radians(self.half_angle)), xp, "the cone",
                                  f"{field}.half_angle", self.center)
        if self.shape == "flat":
            return np.zeros(xp.shape[0])
        code, constants = compile_expression(self.expression, self.dim, f"{field}.expression", self.axisymmetric)
        env = dict(SAFE_FUNCTIONS, **constants, x=xp[:, 0].copy())
        if self.axisymmetric:
            env["r"] = env["x"]
        if self.dim == 3:
            env["y"] = xp[:, 1].copy()
        try:
            with np.errstate(all="ignore"):
                val = np.broadcast_to(np.asarray(eval(code, {"__builtins__": {}}, env), dtype=float), (xp.shape[0],))
        except Exception as exc:
            hint = ("; conditions on x need where(condition, a, b), not 'a if condition else b' or chained "
                    "comparisons" if "truth value" in str(exc) else "")
            raise InputError(f"{field}.expression", f"evaluating {self.expression!r} failed: {exc}{hint}") from None
        return _check_psi(np.array(val), xp, repr(self.expression), f"{field}.expression")


@dataclass(frozen=True)
class Problem:
    """A complete elasto-plastic contact problem (docs/math.md).

    ``path`` is None for Hencky's problem under ``force``. A loading path holds its
    forces in order (:func:`check_forces`), each one backward-Euler step of
    Prandtl-Reuss' law from the unloaded state (docs/evolution.md); ``force`` is then
    the path's largest force, the load every check on the problem's scale judges
    (the mean contact pressure, locking, the solvers' working units).
    """

    mesh: Mesh
    material: Material
    boundary: Boundary
    obstacle: Obstacle
    force: float
    path: tuple[float, ...] | None = None
    axisymmetric: bool = False
    #: depth control (``[load] displacement`` / ``displacement_path``): the rigid body's U
    #: prescribed, F the unknown; ``force`` is then only the first force the search tries
    displacement: float | None = None
    displacement_path: tuple[float, ...] | None = None

    def __post_init__(self) -> None:  # [load] checked also for dataclasses.replace (a force "1" reached numpy)
        if not _finite_number(self.force, "load.force") > 0:
            raise InputError("load.force", f"must be > 0, got {self.force!r}")
        if self.displacement is not None:
            _finite_number(self.displacement, "load.displacement")
        if self.path is not None:
            object.__setattr__(self, "path", check_forces(self.path, "load.path"))
        check_axisymmetric(self.axisymmetric, self.mesh)
        if self.axisymmetric != getattr(self.obstacle, "axisymmetric", self.axisymmetric):
            raise InputError("obstacle", "the obstacle was made for a"
                             + ("n axisymmetric" if self.obstacle.axisymmetric else " plane or 3D")
                             + " model and the problem is not one (make_obstacle(..., axisymmetric=...))")
        if self.displacement_path is not None:
            object.__setattr__(self, "displacement_path",
                               check_depths(self.displacement_path, "load.displacement_path"))

    @property
    def depth_controlled(self) -> bool:
        return self.displacement is not None or self.displacement_path is not None

    @property
    def dim(self) -> int:
        return self.mesh.dim

    def with_force(self, force: float) -> "Problem":
        """The same problem under another load, ``force`` checked as a problem file's
        ``load.force``: a finite number > 0 (not a string, not a boolean)."""
        from dataclasses import replace

        value = _number({"force": force}, "force", "load")
        if not value > 0:
            raise InputError("load.force", f"must be > 0, got {force!r}")
        return replace(self, force=value, path=None, displacement=None, displacement_path=None)

    def with_path(self, forces: Sequence[float]) -> "Problem":
        """The same problem under the loading path ``forces``, checked as a problem
        file's ``load.path`` (:func:`check_forces`)."""
        from dataclasses import replace

        path = check_forces(forces, "load.path")
        return replace(self, force=max(path), path=path, displacement=None, displacement_path=None)


# ----------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------


def _number(section: Mapping, key: str, prefix: str, *, default: Any = None) -> float:
    if key not in section:
        if default is None:
            raise InputError(f"{prefix}.{key}", "is required")
        return default
    return _finite_number(section[key], f"{prefix}.{key}")


def _finite_number(val: Any, field: str) -> float:
    """``val`` as a finite float (:func:`~elastoplast.mesh.base.finite_float`), else an InputError naming ``field``."""
    number = finite_float(val)
    if number is None:
        raise InputError(field, f"must be a finite number, got {short_repr(val)}")
    return number


def _names(section: Mapping, key: str, prefix: str, default: Sequence[str] | None = None) -> tuple[str, ...]:
    if key not in section:
        if default is None:
            raise InputError(f"{prefix}.{key}", "is required")
        return tuple(default)
    val = section[key]
    if isinstance(val, str):
        val = [val]
    if not isinstance(val, (list, tuple)) or not all(isinstance(v, str) for v in val):
        raise InputError(f"{prefix}.{key}", f"must be a list of group names, got {val!r}")
    return tuple(val)


def _only(section: Any, allowed: set[str], prefix: str) -> Mapping:
    if not isinstance(section, Mapping):
        raise InputError(prefix, f"must be a table, got {section!r}")
    unknown = sorted(set(section) - allowed, key=str)
    if unknown:
        raise InputError(f"{prefix}.{unknown[0]}", f"unknown key (allowed: {sorted(allowed)})")
    return section


def make_material(E: float, nu: float, yield_stress: float, hardening: float, *, prefix: str = "material") -> Material:
    """A validated :class:`Material`; warns for perfect plasticity (H = 0). Every
    argument must be a finite number (not a string, a boolean, None or a list)."""
    E, nu, yield_stress, hardening = (_finite_number(val, f"{prefix}.{key}") for key, val in (
        ("E", E), ("nu", nu), ("yield_stress", yield_stress), ("hardening", hardening)))
    material = Material(E, nu, yield_stress, hardening)  # its ranges checked there, named material.<key>
    if nu >= 0.49:
        warnings.warn(f"{prefix}.nu = {nu:.15g} is nearly incompressible (bulk / shear modulus "
                      f"{2 * (1 + nu) / (3 * (1 - 2 * nu)):.3g}): P1 elements lock elastically and the solvers lose "
                      "accuracy", stacklevel=2)
    if hardening == 0:
        warnings.warn(
            f"{prefix}.hardening = 0 is perfect plasticity: stresses are unique up to the limit load but "
            "displacements may not be, and a force above the limit load has no solution; it needs a mesh "
            "whose P1 elements do not lock (in 2D pattern = \"crossed\"; P1 tetrahedra lock: in 3D use "
            "hardening > 0), and meshes that lock are refused by the solvers; 'elastoplast limit' brackets "
            "the limit load on any mesh",
            stacklevel=2,
        )
    return material


def make_obstacle(section: Mapping, dim: int, prefix: str = "obstacle", axisymmetric: bool = False) -> Obstacle:
    """A validated :class:`Obstacle`: the shape's own keys required and checked, and a key
    the shape does not use (``radius`` beside ``flat`` or ``expression``, ``expression``
    beside any other shape) refused rather than ignored. In an axisymmetric model the
    obstacle is a body of revolution about the axis: its centre is the axis (0), and
    ``cylinder`` (a plane-strain shape) is refused."""
    _only(section, {"shape", "radius", "center", "expression", "half_angle"}, prefix)
    shape = section.get("shape")
    shapes = {"sphere", "paraboloid", "cylinder", "cone", "flat", "expression"}
    if not isinstance(shape, str) or shape not in shapes:
        raise InputError(f"{prefix}.shape", f"must be one of {sorted(shapes)}, got {short_repr(shape)}")
    if shape == "cylinder" and dim == 3:
        raise InputError(f"{prefix}.shape", "'cylinder' is the 2D (plane strain) obstacle; use 'sphere' or 'paraboloid' in 3D")
    if shape == "cylinder" and axisymmetric:
        raise InputError(f"{prefix}.shape", "'cylinder' is the plane-strain obstacle; an axisymmetric model is indented "
                                            "by a body of revolution: use 'sphere', 'paraboloid', 'cone', 'flat' or "
                                            "'expression' (in r)")
    if shape == "sphere" and dim == 2 and not axisymmetric:
        shape = "cylinder"  # the same formula with d - 1 = 1
    center = _float_list(section, "center", prefix, dim - 1, default=[0.0] * (dim - 1))
    if axisymmetric and center != [0.0]:
        raise InputError(f"{prefix}.center", f"in an axisymmetric model the obstacle is centred on the axis r = 0, "
                                             f"got {center}: remove the key (or set [0.0])")
    radius = None
    if shape in ("sphere", "cylinder", "paraboloid"):
        radius = _number(section, "radius", prefix)
        if not radius > 0:
            raise InputError(f"{prefix}.radius", f"must be > 0, got {radius!r}")
    half_angle = None
    if shape == "cone":
        half_angle = _number(section, "half_angle", prefix)
        if not 0.0 < half_angle < 90.0:
            raise InputError(f"{prefix}.half_angle", "the angle between the cone's axis and its flank, in degrees, "
                                                     f"must lie in (0, 90), got {half_angle!r}")
    expression = None
    if shape == "expression":
        expression = section.get("expression")
        if not isinstance(expression, str):
            raise InputError(f"{prefix}.expression", "a formula string is required for shape = 'expression'")
        compile_expression(expression, dim, f"{prefix}.expression", axisymmetric)
    written = section["shape"]  # before 'sphere' in 2D became 'cylinder'
    for key, users in (("radius", ("sphere", "cylinder", "paraboloid")), ("expression", ("expression",)),
                       ("half_angle", ("cone",))):
        if key in section and written not in users:  # a key the shape ignores would be dropped without a word
            listed = ", ".join(f'"{u}"' for u in users[:-1]) + (" or " if len(users) > 1 else "") + f'"{users[-1]}"'
            raise InputError(f"{prefix}.{key}", f'only for shape = {listed}, not for shape = "{written}", which does '
                                                "not use it: remove it (or change the shape)")
    return Obstacle(shape=shape, dim=dim, radius=radius, center=tuple(center), expression=expression,
                    half_angle=half_angle, axisymmetric=axisymmetric)


def _float_list(section: Mapping, key: str, prefix: str, n: int, default=None) -> list[float] | None:
    if key not in section:
        return default
    val = section[key]
    floats = [finite_float(v) for v in val] if isinstance(val, (list, tuple)) else []
    if len(floats) != n or any(v is None for v in floats):
        raise InputError(f"{prefix}.{key}", f"must be a list of {n} finite number(s), got {short_repr(val)}")
    return floats


GENERATORS = {"rectangle": 2, "box": 3, "graded": 0}  # graded: 2D or 3D by the length of size


def make_graded_mesh(section: Mapping, prefix: str = "mesh") -> Mesh:
    """The ``graded`` generator (:func:`~elastoplast.mesh.graded.graded_mesh`): ``size``,
    ``contact_radius``, ``h_contact`` and ``h_far`` required; the structured grid's keys refused."""
    for key in ("divisions", "origin", "grading", "contact_center", "pattern"):
        if key in section:
            raise InputError(f"{prefix}.{key}", "does not apply to the 'graded' generator (its body starts at the "
                                                "origin, on the indenter's axis; h_contact and h_far set the sizes)")
    for key in ("size", "contact_radius", "h_contact", "h_far"):
        if key not in section:
            raise InputError(f"{prefix}.{key}", "is required by the 'graded' generator")
    return graded_mesh(section["size"], section["contact_radius"], section["h_contact"], section["h_far"])


def make_mesh(section: Mapping, base_dir: Path, prefix: str = "mesh", axisymmetric: bool = False) -> Mesh:
    """Read ``file`` or run the ``generator``, whose settings :func:`~elastoplast.mesh.base.structured_mesh`
    checks (fields ``mesh.<key>``). An axisymmetric model's rectangle starts on the axis
    (``origin`` [0, 0] unless given), its contact zone a disc about it (``contact_center`` [0] or none)."""
    _only(section, {"file", "generator", "size", "divisions", "origin", "grading", "contact_radius", "contact_center",
                    "pattern", "axisymmetric", "h_contact", "h_far"}, prefix)
    if ("file" in section) == ("generator" in section):
        raise InputError(prefix, "give exactly one of 'file' or 'generator'")
    if "file" in section:
        extra = sorted(set(section) - {"file", "axisymmetric"})
        if extra:
            raise InputError(f"{prefix}.{extra[0]}", "only applies to a built-in generator, not to a mesh file")
        if not isinstance(section["file"], str):
            raise InputError(f"{prefix}.file", f"must be a path, got {section['file']!r}")
        path = Path(section["file"])
        if not path.is_absolute():
            path = base_dir / path
        return read_mesh(path)
    gen = section["generator"]
    if not isinstance(gen, str) or gen not in GENERATORS:
        raise InputError(f"{prefix}.generator", f"must be one of {sorted(GENERATORS)}, got {short_repr(gen)}")
    if gen == "graded":
        return make_graded_mesh(section, prefix)
    dim = GENERATORS[gen]
    for key in ("h_contact", "h_far"):
        if key in section:
            raise InputError(f"{prefix}.{key}", "only applies to the 'graded' generator")
    for key in ("size", "divisions", "contact_radius"):
        if key not in section:
            raise InputError(f"{prefix}.{key}", "is required")
    size = _float_list(section, "size", prefix, dim)  # the generator sets the dimension
    origin, centre = section.get("origin"), section.get("contact_center")
    if axisymmetric and dim == 2:
        origin = [0.0, 0.0] if origin is None else origin
        if centre is not None and not (isinstance(centre, list) and centre in ([0], [0.0]) and centre[0] is not False):
            raise InputError(f"{prefix}.contact_center", "in an axisymmetric model the contact zone is a disc about "
                                                         f"the axis r = 0: leave it out, got {short_repr(centre)}")
        centre = [0.0]
    return structured_mesh(size, section["divisions"], section["contact_radius"], origin=origin,
                           contact_center=centre, grading=section.get("grading", 1.0),
                           pattern=section.get("pattern", "diagonal"))


def default_boundary(mesh: Mesh, axisymmetric: bool = False, graded: bool = False) -> tuple[tuple[str, ...],
                                                                                       tuple[str, ...]]:
    """The paper's setting on a generated block: every face but the bottom clamped (in an
    axisymmetric model, every face but the bottom and the axis); on a graded block in
    plane strain or 3D the symmetry planes (``xmin``, ``ymin``) are not clamped but hold
    u_x = 0 (u_y = 0): the default ``fix_component``."""
    on_axis = np.abs(mesh.points[:, 0]) <= 1e-9 * float(np.ptp(mesh.points, axis=0).max())
    planes = {n for names in symmetry_planes(mesh.dim).values() for n in names} if graded else set()
    clamped = tuple(n for n in mesh.groups if n not in ("bottom", "contact") and n not in planes
                    and not (axisymmetric and np.all(on_axis[np.asarray(mesh.groups[n])])))
    return clamped, ("contact",)


FACETS = {2: "lines", 3: "triangles"}


def make_boundary(section: Mapping, mesh: Mesh, generated: bool, prefix: str = "boundary",
                  axisymmetric: bool = False, graded: bool = False) -> Boundary:
    _only(section, {"clamped", "contact", "fix_component"}, prefix)
    default_clamped, default_contact = default_boundary(mesh, axisymmetric, graded) if generated else (None, None)
    # the axis of an axisymmetric model holds u_r = 0 by itself: no symmetry plane there
    default_fix = symmetry_planes(mesh.dim) if graded and not axisymmetric else {}
    fix_section = _only(section.get("fix_component", default_fix), set(AXES), f"{prefix}.fix_component")
    clamped = _names(section, "clamped", prefix, default_clamped)
    contact = _names(section, "contact", prefix, default_contact)
    fix = {}
    for axis, names in fix_section.items():
        if AXES[axis] >= mesh.dim:
            raise InputError(f"{prefix}.fix_component.{axis}", f"a {mesh.dim}D mesh has no {axis} component")
        fix[AXES[axis]] = _names(fix_section, axis, f"{prefix}.fix_component")
    for key, names in [("clamped", clamped), ("contact", contact)] + [
        (f"fix_component.{a}", fix_section.get(a, ())) for a in fix_section
    ]:
        if isinstance(names, str):
            names = [names]
        for name in names:
            if name in mesh.other_groups:
                raise InputError(f"{prefix}.{key}", f"{name!r} is a {mesh.other_groups[name]}-dimensional physical "
                                                    f"group; boundary groups must be facets ({FACETS[mesh.dim]} in "
                                                    f"{mesh.dim}D): the mesh's facet groups are {sorted(mesh.groups)}")
            if name not in mesh.groups:
                raise InputError(f"{prefix}.{key}", f"unknown group {name!r} (the mesh has {sorted(mesh.groups)})")
    if not contact:
        raise InputError(f"{prefix}.contact", "the contact zone is empty: name at least one group")
    return Boundary(clamped=clamped, contact=contact, fix_component=fix)


def check_generated_contact_zone(mesh: Mesh, boundary: Boundary) -> None:
    """The generator's ``contact`` group (the bottom within ``contact_radius`` of
    ``contact_center``) must hold facets and keep clear of the vertically fixed sides:
    both are settings of ``mesh.contact_radius`` (and ``contact_center``), which the
    user wrote, rather than of ``boundary.contact``, which a generated problem need not
    mention. A vertically fixed group that covers contact facets itself (``contact`` or
    ``bottom`` listed under ``clamped`` or ``fix_component`` on the vertical axis) is the
    boundary list's doing, and that list is named."""
    if "contact" not in boundary.contact:
        return
    facets = mesh.groups["contact"]
    if len(facets) == 0:
        raise InputError("mesh.contact_radius", "no bottom facet lies within contact_radius of contact_center: the "
                                                "contact zone must cover at least one facet of the mesh")
    contact = mesh.group_nodes(["contact"])
    axis = "xyz"[mesh.dim - 1]
    vertical = [("clamped", name) for name in boundary.clamped] + [
        (f"fix_component.{axis}", name) for name in boundary.fix_component.get(mesh.dim - 1, ())]
    for key, name in vertical:
        covered = int(np.all(np.isin(facets, mesh.group_nodes([name])), axis=1).sum())
        if covered:
            what = "clamps" if key == "clamped" else f"fixes the vertical component {axis} of"
            raise InputError(f"boundary.{key}", f"group {name!r} {what} {covered} of the {len(facets)} facets of the "
                                                "contact zone 'contact', which must move with the rigid body: leave "
                                                f"it out of boundary.{key}")
    touched = [name for _, name in vertical if np.intersect1d(mesh.group_nodes([name]), contact).size]
    if touched:
        raise InputError("mesh.contact_radius", f"the contact zone reaches the side(s) {touched}, where the vertical "
                                                "displacement is fixed: keep contact_radius (around contact_center) "
                                                "inside the bottom face")


SECTIONS = {"mesh", "material", "boundary", "obstacle", "load", "solver"}


def problem_from_dict(data: Mapping, base_dir: str | Path | None = ".") -> Problem:
    """Build a :class:`Problem` from the nested structure of the TOML format
    (``base_dir``: the folder a relative mesh file is read from; None is the current one).

    The optional ``[solver]`` table is not part of the problem; it is ignored here
    and read by :func:`elastoplast.solvers.registry.solver_settings`.
    """
    _only(data, SECTIONS, "problem")
    base_dir = "." if base_dir is None else base_dir
    if not isinstance(base_dir, (str, os.PathLike)):
        raise InputError("base_dir", f"must be the folder mesh files are relative to (a path), got {short_repr(base_dir)}")
    for name in (n for n in ("mesh", "material", "obstacle", "load") if n not in data):
        raise InputError(name, "section is required")
    axisymmetric = data["mesh"].get("axisymmetric", False) if isinstance(data["mesh"], Mapping) else False
    mesh = make_mesh(data["mesh"], Path(base_dir), axisymmetric=axisymmetric is True)
    axisymmetric = check_axisymmetric(axisymmetric, mesh)
    mat = _only(data["material"], {"E", "nu", "yield_stress", "hardening"}, "material")
    material = make_material(*(_number(mat, k, "material") for k in ("E", "nu", "yield_stress", "hardening")))
    boundary = make_boundary(data.get("boundary", {}), mesh, generated="generator" in data["mesh"],
                             axisymmetric=axisymmetric, graded=data["mesh"].get("generator") == "graded")
    if "generator" in data["mesh"]:
        check_generated_contact_zone(mesh, boundary)
    obstacle = make_obstacle(data["obstacle"], mesh.dim, axisymmetric=axisymmetric)
    if data["mesh"].get("generator") == "graded" and "boundary" not in data:
        check_centre_on_axis(obstacle.center)
    load = _only(data["load"], {"force", "path", "displacement", "displacement_path"}, "load")
    given = [k for k in ("force", "path", "displacement", "displacement_path") if k in load]
    if len(given) > 1:
        raise InputError("load", "give exactly one of 'force' (Hencky's problem), 'path' (a loading path of Prandtl-"
                                 "Reuss steps), 'displacement' (depth control) or 'displacement_path' (a depth "
                                 f"path), not {' and '.join(given)}")
    if "displacement" in load:
        delta = load["displacement"]
        if isinstance(delta, bool) or not isinstance(delta, (int, float)) or not np.isfinite(delta):
            raise InputError("load.displacement", f"must be a finite number, got {short_repr(delta)}")
        return Problem(mesh=mesh, material=material, boundary=boundary, obstacle=obstacle,
                       force=depth_force_guess(material, mesh, float(delta), axisymmetric),
                       displacement=float(delta), axisymmetric=axisymmetric)
    if "displacement_path" in load:
        depths = check_depths(load["displacement_path"], "load.displacement_path")
        return Problem(mesh=mesh, material=material, boundary=boundary, obstacle=obstacle,
                       force=depth_force_guess(material, mesh, max(depths, key=abs), axisymmetric),
                       displacement_path=depths, axisymmetric=axisymmetric)
    if "path" in load:
        path = check_forces(load["path"], "load.path")
        return Problem(mesh=mesh, material=material, boundary=boundary, obstacle=obstacle, force=max(path),
                       path=path, axisymmetric=axisymmetric)
    if "force" not in load:
        raise InputError("load.force", "is required (or load.path, a loading path of Prandtl-Reuss steps, or "
                                       "load.displacement / load.displacement_path for depth control)")
    force = _number(load, "force", "load")
    if not force > 0:
        raise InputError("load.force", f"must be > 0, got {force!r}")
    return Problem(mesh=mesh, material=material, boundary=boundary, obstacle=obstacle, force=force,
                   axisymmetric=axisymmetric)


MAX_PROBLEM_BYTES = 16 * 2**20  # a problem file is a few hundred bytes


def read_toml(path: str | Path, field: str = "problem", what: str = "problem file") -> dict:
    """Parse a TOML file; every way it can fail is an :class:`InputError` naming ``field``.

    Refused with one line: a missing path, a directory or device, an unreadable or
    empty file, more than ``MAX_PROBLEM_BYTES``, text that is not UTF-8 (a UTF-8 byte
    order mark is skipped), invalid TOML, nesting too deep for the parser, a path
    that is not a string or path.
    """
    path = as_path(path, field, what)
    raw = read_bytes(path, field, what, MAX_PROBLEM_BYTES)
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        raise InputError(field, f"{path} is UTF-16 text; TOML files are UTF-8 (save it as UTF-8)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(field, f"{path} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}): "
                                "TOML files are UTF-8") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(field, f"{path} is not valid TOML: {exc}") from None
    except (RecursionError, MemoryError) as exc:
        raise InputError(field, f"{path} is not valid TOML: nested too deeply ({type(exc).__name__})") from None
    if not data:
        raise InputError(field, f"{path} holds no settings (only comments or blank lines)")
    return data


def load_problem(path: str | Path) -> Problem:
    """Read a problem TOML file; relative mesh paths are relative to it."""
    path = as_path(path, "problem", "problem file")
    return problem_from_dict(read_toml(path), base_dir=path.parent)
