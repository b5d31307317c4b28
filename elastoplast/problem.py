"""Problem description: the Python API and the TOML format.

A :class:`Problem` is fully resolved: a mesh, a material, boundary groups, an
obstacle and a force. :func:`load_problem` reads the TOML format of the README;
:func:`problem_from_dict` takes the same structure as nested dicts. Every
complaint about the input is an :class:`InputError` naming the key.
"""

from __future__ import annotations

import ast
import math
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping, Sequence

import numpy as np

from .errors import InputError
from .material import Material
from .mesh import Mesh, read_mesh, structured_mesh

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


_SAFE_FUNCS = {
    name: getattr(np, name)
    for name in ("sqrt", "exp", "log", "sin", "cos", "tan", "arctan", "arcsin", "arccos",
                 "sinh", "cosh", "tanh", "abs", "minimum", "maximum", "where", "pi", "hypot")
}
_SAFE_FUNCS["e"] = np.e


def _compile_expression(expr: str, dim: int, fieldname: str):
    """Compile a formula in x (and y in 3D) allowing only arithmetic and numpy maths."""
    variables = {"x", "y"} if dim == 3 else {"x"}
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError as exc:
        raise InputError(fieldname, f"cannot parse {expr!r}: {exc.msg}") from None
    allowed = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Call, ast.Name, ast.Load, ast.Constant,
               ast.operator, ast.unaryop, ast.Compare, ast.cmpop, ast.IfExp)
    for node in ast.walk(tree):
        if not isinstance(node, allowed):
            raise InputError(fieldname, f"{type(node).__name__} is not allowed in {expr!r}")
        if isinstance(node, ast.Name) and node.id not in variables and node.id not in _SAFE_FUNCS:
            raise InputError(fieldname, f"unknown name {node.id!r} in {expr!r} (variables: {sorted(variables)})")
    return compile(tree, "<obstacle expression>", "eval")


@dataclass(frozen=True)
class Obstacle:
    """Rigid body surface ``x_d = -psi(x')`` (docs/math.md).

    ``shape``: ``sphere`` (3D) / ``cylinder`` (2D): ``R - sqrt(R^2 - |x'-c|^2)``;
    ``paraboloid``: ``|x'-c|^2 / (2R)``; ``flat``: 0; ``expression``: a formula
    in ``x`` (and ``y`` in 3D).
    """

    shape: str
    dim: int
    radius: float | None = None
    center: tuple[float, ...] = ()
    expression: str | None = None

    def psi(self, xp: np.ndarray, field: str = "obstacle") -> np.ndarray:
        """Evaluate psi at in-plane points ``xp`` (n, d-1); refuses points outside its domain."""
        r2 = np.sum((xp - np.asarray(self.center)) ** 2, axis=1)
        if self.shape in ("sphere", "cylinder"):
            R = self.radius
            if np.sqrt(r2.max(initial=0.0)) >= R:
                raise InputError(
                    f"{field}.radius",
                    f"radius {R:g} is smaller than the contact zone (which reaches {np.sqrt(r2.max()):g} "
                    f"from the centre {list(self.center)})",
                )
            return r2 / (R + np.sqrt(R * R - r2))  # = R - sqrt(R^2 - r^2), without cancellation
        if self.shape == "paraboloid":
            return r2 / (2.0 * self.radius)
        if self.shape == "flat":
            return np.zeros(xp.shape[0])
        code = _compile_expression(self.expression, self.dim, f"{field}.expression")
        env = dict(_SAFE_FUNCS, x=xp[:, 0])
        if self.dim == 3:
            env["y"] = xp[:, 1]
        try:
            with np.errstate(all="ignore"):
                val = np.broadcast_to(np.asarray(eval(code, {"__builtins__": {}}, env), dtype=float), (xp.shape[0],))
        except Exception as exc:
            raise InputError(f"{field}.expression", f"evaluating {self.expression!r} failed: {exc}") from None
        if not np.all(np.isfinite(val)):
            raise InputError(f"{field}.expression", f"{self.expression!r} is not finite at every contact node")
        return np.array(val)


@dataclass(frozen=True)
class Problem:
    """A complete elasto-plastic contact problem (docs/math.md)."""

    mesh: Mesh
    material: Material
    boundary: Boundary
    obstacle: Obstacle
    force: float

    @property
    def dim(self) -> int:
        return self.mesh.dim


# ----------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------


def _number(section: Mapping, key: str, prefix: str, *, default: Any = None) -> float:
    if key not in section:
        if default is None:
            raise InputError(f"{prefix}.{key}", "is required")
        return default
    val = section[key]
    if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
        raise InputError(f"{prefix}.{key}", f"must be a finite number, got {val!r}")
    return float(val)


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
    unknown = sorted(set(section) - allowed)
    if unknown:
        raise InputError(f"{prefix}.{unknown[0]}", f"unknown key (allowed: {sorted(allowed)})")
    return section


def make_material(E: float, nu: float, yield_stress: float, hardening: float, *, prefix: str = "material") -> Material:
    """A validated :class:`Material`; warns for perfect plasticity (H = 0)."""
    if not E > 0:
        raise InputError(f"{prefix}.E", f"must be > 0, got {E!r}")
    if not -1.0 < nu < 0.5:
        raise InputError(f"{prefix}.nu", f"must lie in (-1, 0.5), got {nu!r}")
    if not yield_stress > 0:
        raise InputError(f"{prefix}.yield_stress", f"must be > 0, got {yield_stress!r}")
    if not hardening >= 0:
        raise InputError(f"{prefix}.hardening", f"must be >= 0, got {hardening!r}")
    if hardening == 0:
        warnings.warn(
            "hardening = 0 is perfect plasticity: stresses are unique up to the limit load but "
            "displacements may not be, and a force above the limit load has no solution",
            stacklevel=2,
        )
    return Material(float(E), float(nu), float(yield_stress), float(hardening))


def make_obstacle(section: Mapping, dim: int, prefix: str = "obstacle") -> Obstacle:
    _only(section, {"shape", "radius", "center", "expression"}, prefix)
    shape = section.get("shape")
    shapes = {"sphere", "paraboloid", "cylinder", "flat", "expression"}
    if shape not in shapes:
        raise InputError(f"{prefix}.shape", f"must be one of {sorted(shapes)}, got {shape!r}")
    if shape == "cylinder" and dim == 3:
        raise InputError(f"{prefix}.shape", "'cylinder' is the 2D (plane strain) obstacle; use 'sphere' or 'paraboloid' in 3D")
    if shape == "sphere" and dim == 2:
        shape = "cylinder"  # the same formula with d - 1 = 1
    center = section.get("center", [0.0] * (dim - 1))
    if (not isinstance(center, (list, tuple)) or len(center) != dim - 1
            or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in center)):
        raise InputError(f"{prefix}.center", f"must be a list of {dim - 1} number(s), got {center!r}")
    radius = None
    if shape in ("sphere", "cylinder", "paraboloid"):
        radius = _number(section, "radius", prefix)
        if not radius > 0:
            raise InputError(f"{prefix}.radius", f"must be > 0, got {radius!r}")
    expression = None
    if shape == "expression":
        expression = section.get("expression")
        if not isinstance(expression, str):
            raise InputError(f"{prefix}.expression", "a formula string is required for shape = 'expression'")
        _compile_expression(expression, dim, f"{prefix}.expression")
    return Obstacle(shape=shape, dim=dim, radius=radius, center=tuple(float(c) for c in center), expression=expression)


def _int_list(section: Mapping, key: str, prefix: str, n: int) -> list[int]:
    val = section.get(key)
    if (not isinstance(val, (list, tuple)) or len(val) != n
            or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in val)):
        raise InputError(f"{prefix}.{key}", f"must be a list of {n} positive integers, got {val!r}")
    return list(val)


def _float_list(section: Mapping, key: str, prefix: str, n: int, default=None) -> list[float] | None:
    if key not in section:
        return default
    val = section[key]
    if (not isinstance(val, (list, tuple)) or len(val) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in val)):
        raise InputError(f"{prefix}.{key}", f"must be a list of {n} numbers, got {val!r}")
    return [float(v) for v in val]


GENERATORS = {"rectangle": 2, "box": 3}


def make_mesh(section: Mapping, base_dir: Path, prefix: str = "mesh") -> Mesh:
    """Read ``file`` or run the ``generator`` ('rectangle' 2D, 'box' 3D)."""
    _only(section, {"file", "generator", "size", "divisions", "origin", "grading", "contact_radius", "contact_center",
                    "pattern"}, prefix)
    if ("file" in section) == ("generator" in section):
        raise InputError(prefix, "give exactly one of 'file' or 'generator'")
    if "file" in section:
        extra = sorted(set(section) - {"file"})
        if extra:
            raise InputError(f"{prefix}.{extra[0]}", "only applies to a built-in generator, not to a mesh file")
        if not isinstance(section["file"], str):
            raise InputError(f"{prefix}.file", f"must be a path, got {section['file']!r}")
        path = Path(section["file"])
        if not path.is_absolute():
            path = base_dir / path
        return read_mesh(path)
    gen = section["generator"]
    if gen not in GENERATORS:
        raise InputError(f"{prefix}.generator", f"must be one of {sorted(GENERATORS)}, got {gen!r}")
    dim = GENERATORS[gen]
    size = _float_list(section, "size", prefix, dim)
    if size is None or min(size) <= 0:
        raise InputError(f"{prefix}.size", f"{dim} positive lengths are required, got {section.get('size')!r}")
    divisions = _int_list(section, "divisions", prefix, dim)
    grading = _number(section, "grading", prefix, default=1.0)
    if not grading >= 1.0:
        raise InputError(f"{prefix}.grading", f"must be >= 1 (1 is uniform), got {grading!r}")
    radius = _number(section, "contact_radius", prefix)
    if not radius > 0:
        raise InputError(f"{prefix}.contact_radius", f"must be > 0, got {radius!r}")
    origin = _float_list(section, "origin", prefix, dim)
    center = _float_list(section, "contact_center", prefix, dim - 1)
    pattern = section.get("pattern", "diagonal")
    if pattern not in ("diagonal", "crossed") or (pattern == "crossed" and dim == 3):
        raise InputError(f"{prefix}.pattern", f"must be 'diagonal' or (2D only) 'crossed', got {pattern!r}")
    if origin is not None and origin[-1] != 0.0:
        raise InputError(f"{prefix}.origin", "the body must sit on the contact plane: the last coordinate must be 0")
    return structured_mesh(size, divisions, radius, origin=origin, contact_center=center, grading=grading,
                           pattern=pattern)


def default_boundary(mesh: Mesh) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The paper's setting on a generated block: every face but the bottom clamped."""
    clamped = tuple(n for n in mesh.groups if n not in ("bottom", "contact"))
    return clamped, ("contact",)


def make_boundary(section: Mapping, mesh: Mesh, generated: bool, prefix: str = "boundary") -> Boundary:
    _only(section, {"clamped", "contact", "fix_component"}, prefix)
    default_clamped, default_contact = default_boundary(mesh) if generated else (None, None)
    fix_section = _only(section.get("fix_component", {}), set(AXES), f"{prefix}.fix_component")
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
            if name not in mesh.groups:
                raise InputError(f"{prefix}.{key}", f"unknown group {name!r} (the mesh has {sorted(mesh.groups)})")
    if not contact:
        raise InputError(f"{prefix}.contact", "the contact zone is empty: name at least one group")
    return Boundary(clamped=clamped, contact=contact, fix_component=fix)


SECTIONS = {"mesh", "material", "boundary", "obstacle", "load", "solver"}


def problem_from_dict(data: Mapping, base_dir: str | Path = ".") -> Problem:
    """Build a :class:`Problem` from the nested structure of the TOML format.

    The optional ``[solver]`` table is not part of the problem; it is ignored here
    and read by :func:`elastoplast.solvers.solver_settings`.
    """
    _only(data, SECTIONS, "problem")
    for name in ("mesh", "material", "obstacle", "load"):
        if name not in data:
            raise InputError(name, "section is required")
    mesh = make_mesh(data["mesh"], Path(base_dir))
    mat = _only(data["material"], {"E", "nu", "yield_stress", "hardening"}, "material")
    material = make_material(*(_number(mat, k, "material") for k in ("E", "nu", "yield_stress", "hardening")))
    boundary = make_boundary(data.get("boundary", {}), mesh, generated="generator" in data["mesh"])
    obstacle = make_obstacle(data["obstacle"], mesh.dim)
    load = _only(data["load"], {"force"}, "load")
    force = _number(load, "force", "load")
    if not force > 0:
        raise InputError("load.force", f"must be > 0, got {force!r}")
    return Problem(mesh=mesh, material=material, boundary=boundary, obstacle=obstacle, force=force)


def read_toml(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise InputError("problem", f"file not found: {path}")
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise InputError("problem", f"{path} is not valid TOML: {exc}") from None


def load_problem(path: str | Path) -> Problem:
    """Read a problem TOML file; relative mesh paths are relative to it."""
    path = Path(path)
    return problem_from_dict(read_toml(path), base_dir=path.parent)
