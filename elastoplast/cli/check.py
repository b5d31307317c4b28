"""``elastoplast check PROBLEM.toml ANSWER [--tol T] [--bounds] [--out DIR]``: the KKT
certificate of an answer computed anywhere (another program, another method, by hand).

ANSWER is one of:

* an ``.npz`` holding ``u`` (``n_nodes x d``: the total nodal displacements, zero at the
  fixed components, in the problem's units) and ``U`` (one number, the rigid body's
  displacement); optionally ``sigma`` (``n_elements x k``, Mandel order of docs/math.md:
  2D ``s11, s22, s33, sqrt2 s12``, 3D ``s11, s22, s33, sqrt2 s23, sqrt2 s13, sqrt2 s12``)
  and ``xi`` (``n_elements``), both or neither;
* a ``.vtu`` with point data ``displacement`` (``n_nodes x 3``, or ``x d``; in 2D the third
  column zero) and field data ``U``, or, lacking that, the ``summary.json`` written beside
  it by ``elastoplast solve`` (meshio does not write field data to VTU files, so the
  ``solution.vtu`` of a solve carries U there). Its points must be the mesh's nodes, in
  the same order or in any other (then matched by position, with a note).

Node order (:func:`node_order`): the order of the points of ``solution.vtu``, which is
that of ``Discretization.mesh.points``. For a mesh file: the file's nodes that some
triangle or tetrahedron uses, in file order; nodes no simplex uses (gmsh's geometry
points) are dropped, and of coincident nodes (closer than ``MERGE_TOLERANCE`` times the
mesh extent, merged with a warning) only the first in file order stays. For the
generators: ``i + (nx+1) j [+ (nx+1)(ny+1) k]`` on the grid of grid lines, x fastest;
``pattern = "crossed"`` appends the centres of the squares, x fastest. Elements (for
``sigma``, ``xi``): the mesh's order, the file's simplices in file order.

The answer is judged like every built-in method's: when ``sigma``/``xi`` are absent the
stresses are the return mapping of the strains of ``u``; the contact forces are those
the stresses imply (``N r``, as :func:`~elastoplast.certificate.solution.make_solution`
takes them when a method gives none); :func:`~elastoplast.certificate.kkt.certify`
measures the eight residuals (``dirichlet`` on ``u`` as given). It is certified when every
residual is at most ``tol`` and its strains stay within the small-strain model.
``--bounds`` adds the continuum upper bound of this displacement field
(:func:`~elastoplast.bounds.upper.upper_bound`), the lower bound of the equilibrium
element and their energy and U brackets, as ``elastoplast bounds`` prints them.

Exit codes: 0 certified (with ``--bounds``: and the bracket certified), 1 not certified,
2 bad input (:class:`~elastoplast.errors.InputError`: one line naming the array, e.g.
``ANSWER.u: expected (861, 2), got (861, 3)``). Nothing is written unless ``out``
is given.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import re
import sys
import time
import warnings
import zipfile
from dataclasses import replace
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from elastoplast.certificate.kkt import KKTResiduals, certify
from elastoplast.certificate.solution import Solution, Status, make_solution
from elastoplast.cli.exits import EXIT_NOT_CONVERGED, EXIT_OK
from elastoplast.errors import InputError, expect, short_repr
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import return_mapping
from elastoplast.limits import (
    as_path,
    check_input_file,
    check_memory,
    mesh_read_bytes,
    read_bytes,
    shown,
)
from elastoplast.options import SolverOptions
from elastoplast.cli.printing import discretize_file, figure, problem_line

#: how the answer's arrays are named in messages
FIELD = "ANSWER"
#: the arrays an .npz answer may hold
NPZ_ARRAYS = ("u", "U", "sigma", "xi")
#: VTU points match the mesh's nodes within this share of the mesh extent ...
POINT_TOLERANCE = 1e-6
#: ... and within this share of its shortest edge
POINT_EDGE_SHARE = 0.1
#: the method name the answer's Solution carries (summary.json's "method")
METHOD = "answer"
#: the largest summary.json read beside a VTU answer (a solve's is a few KiB)
SUMMARY_LIMIT = 4 * 2**20
#: the largest stress scale (E |u| / shortest edge, |sigma|, |xi|) the certificate takes:
#: beyond it its squares and energies overflow floating point (no small-strain answer comes near)
MAX_MAGNITUDE = 1e100
#: the first bytes of an .npz (a zip archive) and of a VTU (XML)
ZIP_MAGIC = b"PK\x03\x04"
XML_STARTS = (b"<?xml", b"<VTKFile")


# ----------------------------------------------------------------------------
# reading the answer
# ----------------------------------------------------------------------------


def node_order(disc: Discretization) -> np.ndarray:
    """The node coordinates ``(n_nodes, d)`` in the order an answer's ``u`` follows
    (the points of ``solution.vtu``; see the module docstring for the rule)."""
    return disc.mesh.points


def expected_shapes(disc: Discretization) -> dict[str, tuple[int, ...]]:
    """The shape of each array of an answer on ``disc``."""
    return {"u": (disc.mesh.n_nodes, disc.dim), "U": (), "sigma": (disc.n_elements, disc.k), "xi": (disc.n_elements,)}


def shape_text(shape: tuple[int, ...]) -> str:
    return "a single number" if shape == () else str(tuple(int(s) for s in shape))


def check_shape(name: str, shape: tuple[int, ...], disc: Discretization) -> None:
    """Refuse an array of ``name`` whose shape is not the one expected (``U``: one number,
    shape ``()`` or ``(1,)``), naming it ``ANSWER.name`` with both shapes."""
    want = expected_shapes(disc)[name]
    shape = tuple(int(s) for s in shape)
    if shape == want or (want == () and shape == (1,)):
        return
    hint = ""
    if name == "u" and len(shape) >= 1 and shape[0] != want[0]:
        hint = f"; the problem's mesh has {want[0]} nodes (the points of its solution.vtu, in their order)"
    elif name in ("sigma", "xi") and len(shape) >= 1 and shape[0] != want[0]:
        hint = f"; the problem's mesh has {want[0]} elements"
    elif name == "sigma" and len(shape) == 2:
        hint = f"; {disc.dim}D stresses have {disc.k} Mandel components (docs/math.md)"
    raise InputError(f"{FIELD}.{name}", f"expected {shape_text(want)}, got {shape_text(shape)}{hint}")


def check_values(name: str, arr: np.ndarray) -> np.ndarray:
    """``arr`` as floats, refusing anything but real numbers and any NaN or infinity."""
    if arr.dtype.kind not in "iuf":
        raise InputError(f"{FIELD}.{name}", f"expected real numbers, got an array of {arr.dtype}")
    arr = arr.astype(float)
    bad = ~np.isfinite(arr)
    if np.any(bad):
        first = np.argwhere(bad)[0]
        where = f" (first at row {int(first[0])})" if arr.ndim >= 1 else ""
        raise InputError(f"{FIELD}.{name}", f"{int(bad.sum())} NaN or infinite value(s){where}")
    return arr


def npy_header(zf: zipfile.ZipFile, member: str, name: str) -> tuple[tuple[int, ...], np.dtype]:
    """``(shape, dtype)`` of one array of an .npz, read from its header only (an array
    of the wrong shape is refused before its data are read)."""
    fmt = np.lib.format
    try:
        with zf.open(member) as fh:
            version = fmt.read_magic(fh)
            reader = fmt.read_array_header_1_0 if version == (1, 0) else fmt.read_array_header_2_0
            shape, _, dtype = reader(fh)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, RuntimeError) as exc:
        raise InputError(f"{FIELD}.{name}", f"cannot read it: {exc}") from None
    return tuple(shape), np.dtype(dtype)


def read_npz(path: Path, disc: Discretization) -> dict[str, np.ndarray]:
    """The arrays of an .npz answer, each checked (shape first, then values)."""
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise InputError(FIELD, f"cannot read {shown(path)} as an .npz: {exc}") from None
    with zf:
        members = {m[:-4]: m for m in zf.namelist() if m.endswith(".npy")}
        for name in ("u", "U"):
            if name not in members:
                held = ", ".join(sorted(members)) or "no arrays"
                raise InputError(f"{FIELD}.{name}", f"missing (the .npz holds {held})")
        given = [n for n in ("sigma", "xi") if n in members]
        if len(given) == 1:
            other = "xi" if given == ["sigma"] else "sigma"
            raise InputError(f"{FIELD}.{other}", f"missing ({given[0]} is given: give both, or neither for the "
                                                 "stresses of the return mapping of u)")
        ignored = sorted(set(members) - set(NPZ_ARRAYS))
        if ignored:
            warnings.warn(f"{FIELD}: array(s) {', '.join(ignored)} ignored (an answer holds u, U and optionally "
                          "sigma, xi; the contact forces are those the stresses imply)")
        arrays = {}
        for name in [n for n in NPZ_ARRAYS if n in members]:
            shape, dtype = npy_header(zf, members[name], name)
            if dtype.kind not in "iuf":
                raise InputError(f"{FIELD}.{name}", f"expected real numbers, got an array of {dtype}")
            check_shape(name, shape, disc)
            try:
                with zf.open(members[name]) as fh:
                    arr = np.lib.format.read_array(fh, allow_pickle=False)
            except (ValueError, OSError, EOFError, zipfile.BadZipFile, RuntimeError) as exc:
                raise InputError(f"{FIELD}.{name}", f"cannot read it: {exc}") from None
            arrays[name] = check_values(name, arr)
    return arrays


def read_vtu_mesh(path: Path):
    """``meshio.read`` of a VTU, every way it fails an InputError naming ANSWER (meshio
    prints its complaints and may end with ``sys.exit``; both are captured)."""
    import meshio

    check_memory(mesh_read_bytes(path, path.stat().st_size), FIELD, f"reading {shown(path)}", "give an .npz answer")
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return meshio.read(path, file_format="vtu")
    except (Exception, SystemExit) as exc:
        why = vtu_failure(exc, out.getvalue())
        raise InputError(FIELD, f"cannot read {shown(path)} as a VTU: {why}"[:500]) from None


def vtu_failure(exc: BaseException, printed: str) -> str:
    """Why meshio could not read a VTU, readably: what it printed, its own ReadError or
    the XML parser's message; never a ``SystemExit`` code or an internal Python error
    (an empty ``DataArray`` makes meshio fail with an AttributeError)."""
    import xml.etree.ElementTree as ET

    import meshio

    said = " ".join(printed.split())
    if said:
        return said
    if isinstance(exc, ET.ParseError):
        return f"not well-formed XML ({exc})"
    if isinstance(exc, (meshio.ReadError, ValueError)) and str(exc).strip():
        return " ".join(str(exc).split())
    return ("malformed VTU content (a DataArray that is empty, truncated or of another size than declared, or a "
            "missing attribute)")


def matching_nodes(disc: Discretization, points: np.ndarray) -> np.ndarray | None:
    """``order`` with ``points[order]`` the mesh's nodes (within :data:`POINT_TOLERANCE`
    of the extent and :data:`POINT_EDGE_SHARE` of the shortest edge), or None when the
    points are not the mesh's nodes in any order."""
    from scipy.spatial import cKDTree

    from elastoplast.mesh.base import shortest_edge

    nodes = node_order(disc)
    if points.shape != nodes.shape:
        return None
    extent = float(np.max(nodes.max(axis=0) - nodes.min(axis=0)))
    tol = min(POINT_TOLERANCE * extent, POINT_EDGE_SHARE * shortest_edge(nodes, disc.mesh.cells))
    if np.all(np.abs(points - nodes) <= tol):
        return np.arange(len(nodes))
    dist, nearest = cKDTree(points).query(nodes)
    if np.all(dist <= tol) and np.unique(nearest).size == len(nodes):
        return nearest
    return None


def vtu_U(path: Path, m, disc: Discretization) -> np.ndarray:
    """The answer's U: the VTU's field data ``U``, else the ``summary.json`` beside it."""
    if "U" in (m.field_data or {}):
        return np.asarray(m.field_data["U"])
    summary = path.parent / "summary.json"
    if not summary.is_file():
        raise InputError(f"{FIELD}.U", f"missing: {shown(path)} has no field data U and no summary.json lies beside "
                                       "it (give an .npz with u and U)")
    raw = read_bytes(summary, f"{FIELD}.U", "summary.json", SUMMARY_LIMIT)
    try:
        data = json.loads(raw.decode("utf-8"))
    except (ValueError, RecursionError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise InputError(f"{FIELD}.U", f"cannot read U from {shown(summary)}: {exc}"[:500]) from None
    if not isinstance(data, Mapping) or "U" not in data:
        raise InputError(f"{FIELD}.U", f"missing: {shown(summary)} has no U")
    n_nodes = data.get("n_nodes", disc.mesh.n_nodes)
    if isinstance(n_nodes, bool) or not isinstance(n_nodes, int):
        raise InputError(f"{FIELD}.U", f"{shown(summary)}: n_nodes must be an integer (the node count of the "
                                       f"solve's mesh), got {short_repr(n_nodes)}")
    if n_nodes != disc.mesh.n_nodes:
        raise InputError(f"{FIELD}.U", f"{shown(summary)} belongs to a mesh of {data['n_nodes']} nodes, not this "
                                       f"problem's {disc.mesh.n_nodes}")
    value = step_U(path, data, summary)
    if isinstance(value, bool) or not isinstance(value, (int, float)):  # strict JSON: a NaN was written as null
        raise InputError(f"{FIELD}.U", f"expected a number in {shown(summary)}, got {value!r}")
    return np.asarray(float(value))


def step_U(path: Path, data: Mapping, summary: Path) -> Any:
    """U for ``path`` from its ``summary.json``: a loading path's step file
    (``solution_NNN.vtu``) takes that step's entry of ``"path"``, not the last step's U."""
    match = re.fullmatch(r"solution_(\d+)\.vtu", path.name)
    steps = data.get("path")
    if match is None or not isinstance(steps, list):
        return data["U"]
    index = int(match.group(1))
    entry = next((e for e in steps if isinstance(e, Mapping) and e.get("step") == index), None)
    if entry is None or "U" not in entry:
        raise InputError(f"{FIELD}.U", f"{shown(summary)} has no step {index} with a U in its \"path\" "
                                       f"(for {shown(path)})")
    return entry["U"]


def read_vtu(path: Path, disc: Discretization) -> dict[str, np.ndarray]:
    """``u`` and ``U`` of a VTU answer (point data ``displacement``), in the mesh's node order."""
    m = read_vtu_mesh(path)
    d, n = disc.dim, disc.mesh.n_nodes
    if "displacement" not in m.point_data:
        held = ", ".join(sorted(m.point_data)) or "none"
        raise InputError(f"{FIELD}.displacement", f"missing: the VTU has no point data 'displacement' (it has {held})")
    disp = np.asarray(m.point_data["displacement"])
    if disp.ndim != 2 or disp.shape[0] != n or disp.shape[1] not in (d, 3):
        wanted = f"({n}, 3)" if d == 3 else f"({n}, {d}) or ({n}, 3)"
        raise InputError(f"{FIELD}.displacement", f"expected {wanted}, got {shape_text(disp.shape)}"
                                                  + (f"; the problem's mesh has {n} nodes" if disp.shape[:1] != (n,)
                                                     else ""))
    disp = check_values("displacement", disp)
    if disp.shape[1] > d and np.any(disp[:, d:] != 0):
        raise InputError(f"{FIELD}.displacement", f"a {d}D problem: its third column must be zero, got values up to "
                                                  f"{np.abs(disp[:, d:]).max():.3g}")
    points = np.asarray(m.points, dtype=float)
    if points.ndim != 2 or points.shape[1] < d:
        raise InputError(f"{FIELD}.points", f"expected {d}D points, got {shape_text(points.shape)}")
    if np.any(points[:, d:] != 0):
        raise InputError(f"{FIELD}.points", f"some have z != 0: not the nodes of this {d}D problem's mesh")
    order = matching_nodes(disc, points[:, :d])
    if order is None:
        raise InputError(f"{FIELD}.points", f"the VTU's {len(points)} points are not the {n} nodes of the problem's "
                                            "mesh (in any order): the answer was computed on another mesh")
    if np.any(order != np.arange(n)):
        print(f"note: {FIELD}: the VTU's points are the mesh's nodes in another order; matched by position",
              file=sys.stderr)
    U = np.asarray(vtu_U(path, m, disc))
    if U.dtype.kind in "iuf":
        check_shape("U", U.shape, disc)
    return {"u": disp[order, :d], "U": check_values("U", U)}


def answer_format(path: Path) -> str:
    """``"npz"`` or ``"vtu"``: by the first bytes (a zip archive, XML), whatever the
    suffix says; a note when the suffix says otherwise."""
    suffix = path.suffix.lower()
    with open(path, "rb") as fh:
        head = fh.read(256)
    head = head.removeprefix(b"\xef\xbb\xbf").lstrip()  # a UTF-8 byte order mark, blank lines
    fmt = "npz" if head.startswith(ZIP_MAGIC) else "vtu" if head.startswith(XML_STARTS) else None
    if fmt is None:
        what = {".npz": "an .npz: it is not a zip archive", ".vtu": "a VTU: it is not an XML file"}.get(suffix)
        if what:
            raise InputError(FIELD, f"cannot read {shown(path)} as {what} (it starts with {head[:16]!r})")
        raise InputError(FIELD, f"{shown(path)} is neither an .npz (arrays u, U) nor a .vtu (point data "
                                "displacement)")
    if suffix in (".npz", ".vtu") and suffix[1:] != fmt:
        print(f"note: {FIELD}: {path.name} is {'an .npz (a zip archive)' if fmt == 'npz' else 'a VTU (XML)'} "
              "whatever its suffix says; read as one", file=sys.stderr)
    return fmt


def read_answer(path: str | Path, disc: Discretization) -> dict[str, Any]:
    """The answer in ``path`` as ``{"u": (n_nodes, d), "U": float, "sigma": (n_el, k) |
    None, "xi": (n_el,) | None, "format": "npz" | "vtu"}``, every array checked against
    ``disc``: an InputError naming ``ANSWER.<array>`` for a missing array, a wrong shape
    or node count, a NaN or infinity, or a file that cannot be read."""
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    path = as_path(path, FIELD, "answer file")
    check_input_file(path, FIELD, "answer file")
    try:
        fmt = answer_format(path)
    except OSError as exc:
        raise InputError(FIELD, f"cannot read {shown(path)}: {exc.strerror or exc}") from None
    arrays = read_npz(path, disc) if fmt == "npz" else read_vtu(path, disc)
    return {"u": arrays["u"], "U": float(arrays["U"].reshape(-1)[0]), "sigma": arrays.get("sigma"),
            "xi": arrays.get("xi"), "format": fmt}


# ----------------------------------------------------------------------------
# the certificate
# ----------------------------------------------------------------------------


def check_tolerance(tol: Any, table: Any) -> float:
    """``tol`` (``--tol``), else the problem file's ``solver.tol``, else the default of
    :class:`~elastoplast.options.SolverOptions` (1e-6); checked in the same range."""
    if tol is not None:
        try:
            return SolverOptions.build({"tol": tol}).tol
        except InputError as exc:
            raise InputError("--tol", exc.message) from None
    if table is not None and not isinstance(table, Mapping):
        raise InputError("solver", f"must be a table, got {type(table).__name__}")
    if table and "tol" in table:
        return SolverOptions.build({"tol": table["tol"]}, prefix="solver.").tol
    return SolverOptions().tol


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


# ----------------------------------------------------------------------------
# the command
# ----------------------------------------------------------------------------


def residual_lines(kkt: KKTResiduals, tol: float) -> list[str]:
    """One line per residual: name, value, the comparison with ``tol``, ok or FAIL."""
    width = max(len(name) for name in kkt.as_dict())
    return [f"{name:<{width}}  {value:.2e} {'<=' if value <= tol else '> '} {tol:.3g}  "
            f"{'ok' if value <= tol else 'FAIL'}" for name, value in kkt.as_dict().items()]


#: ``check --bounds``'s lower bound: the global program (an answer's stresses need not balance to round-off)
GLOBAL = {"kind": "global"}


def _bounds(disc: Discretization, sol: Solution):
    """The energy and U brackets of the answer's displacement field (a
    :class:`~elastoplast.bounds.bracket.BoundsReport`), built from the same pieces as
    :func:`~elastoplast.bounds.bracket.certified_bounds` with the upper bound of this
    field instead of a solve's: the field with its fixed components at zero (the
    ``dirichlet`` residual judges whether the answer had them so; the bound is that of
    the admissible field it implies)."""
    from elastoplast.bounds.bracket import BoundsReport, combine, lower_bound, u_bracket_of
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


def bounds_line(report, U: float) -> str:
    """The bracket as ``elastoplast bounds`` prints it."""
    b = report.bounds
    return (f"energy in [{b.energy_lower:.8g}, {b.energy_upper:.8g}] (relative gap {b.energy_gap_rel:.2e}); "
            f"U in [{report.U_lower:.6g}, {report.U_upper:.6g}] (answer's U = {U:.6g}); stress error <= "
            f"{b.stress_error_bound:.4g} ({100 * b.stress_error_bound_rel:.2f}%); "
            f"{'certified' if report.certified else 'NOT certified'}")


def run_check(problem_path: str | Path, answer_path: str | Path, tol: float | None = None, bounds: bool = False,
              out: str | Path | None = None, quiet: bool = False) -> int:
    """``elastoplast check``: certify the answer in ``answer_path`` for the problem in
    ``problem_path``; print one line per KKT residual, with ``bounds`` the bracket, and
    a verdict line; with ``out`` write ``summary.json`` and ``solution.vtu`` there.

    Returns the exit code: 0 certified (with ``bounds``: the bracket too), 1 not.
    Bad input raises :class:`InputError` naming the field (``ANSWER.u``, ``--tol``,
    ``--out``, the problem file's keys), which the command line turns into exit code 2.
    """
    from elastoplast.io.output import check_output_dir
    from elastoplast.problem.definition import read_toml

    t0 = time.perf_counter()
    problem_path = as_path(problem_path, "problem", "problem file")
    data = read_toml(problem_path)
    tol = check_tolerance(tol, data.get("solver"))
    if out is not None:
        check_output_dir(out, "--out")
    check_input_file(as_path(answer_path, FIELD, "answer file"), FIELD, "answer file")  # before the mesh is built
    if out is not None:
        check_out_keeps_inputs(out, problem_path, Path(answer_path))
    disc = discretize_file(problem_path, data)
    answer = read_answer(answer_path, disc)
    if bounds:
        from elastoplast.bounds.lower import SEQUENCE_MEMORY_FACTOR, LowerBoundOptions, check_lower_bound_size

        check_lower_bound_size(disc, LowerBoundOptions(), factor=SEQUENCE_MEMORY_FACTOR)
    if not quiet:
        stresses = "sigma, xi as given" if answer["sigma"] is not None else "stresses by the return mapping of u"
        print(problem_line(problem_path, disc, f"checking {Path(answer_path).name} ({stresses}), tol {tol:g}"
                                                + ("; then the bounds" if bounds else "")), file=sys.stderr)
    sol = certify_answer(disc, answer, tol, seconds=time.perf_counter() - t0)
    report = _bounds(disc, sol) if bounds else None  # before any output: it may refuse the input (load.force)
    for line in residual_lines(sol.kkt, tol):
        print(line)
    if report is not None:
        print(bounds_line(report, sol.U))
    certified = sol.converged and (report is None or report.certified)
    extra = {"check": {"answer": str(answer_path), "format": answer["format"], "tol": tol,
                       "stresses": "given" if answer["sigma"] is not None else "return mapping",
                       "certified": certified}}
    if report is not None:
        extra.update(report.as_dict())
    written = ""
    if out is not None:
        from elastoplast.bounds.bracket import gap_fields
        from elastoplast.cli.results import write_results

        vtu = gap_fields(disc, report.bounds) if report is not None else {}
        write_results(out, disc, sol, extra=extra, field="--out", **vtu)
        written = f" -> {Path(out) / 'summary.json'}"
    print(verdict_line(sol, report, certified) + written)
    return EXIT_OK if certified else EXIT_NOT_CONVERGED


def check_out_keeps_inputs(out: str | Path, problem_path: Path, answer_path: Path) -> None:
    """Refuse an ``--out`` folder holding (at any depth) the answer (and so the
    ``summary.json`` read beside it) or the problem file: the results would replace them."""
    from elastoplast.io.output import path_errors

    with path_errors(out, "--out"):
        folder = Path(out).expanduser().resolve()
        inputs = {"the answer": answer_path.expanduser().resolve(), "the problem file": problem_path.resolve()}
    for what, path in inputs.items():
        if folder in path.parents:
            beside = " and the summary.json beside it" if what == "the answer" else ""
            raise InputError("--out", f"{shown(out)} holds {what} ({shown(path)}{beside}), which the results would "
                                      "replace; name another folder")


def verdict_line(sol: Solution, report, certified: bool) -> str:
    """``certified: ...`` or ``NOT certified: ...`` with the reason."""
    if certified:
        return f"certified: {sol.message}; U = {figure(sol.U, '.6g')}, duality gap {figure(sol.duality_gap, '.2e')}"
    if not sol.converged:
        return f"NOT certified: {sol.message}"
    return (f"NOT certified: the KKT residuals pass, the bounds do not (upper: {report.upper.message}; lower: "
            f"{report.lower.message})")
