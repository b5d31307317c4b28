"""Reading an answer computed anywhere (another program, another method, by hand) back
onto a problem's discretisation: the arrays of an ``.npz`` or the point data of a
``solution.vtu`` with its U (field data, or the ``summary.json`` beside it), every array
checked against the mesh (:func:`read_answer`). ``elastoplast check`` certifies what it
reads (:mod:`elastoplast.studies.answer`).

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
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import sys
import warnings
import zipfile
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from elastoplast.errors import InputError, expect, short_repr
from elastoplast.fem.discretize import Discretization
from elastoplast.limits import (
    as_path,
    check_input_file,
    check_memory,
    mesh_read_bytes,
    read_bytes,
    shown,
)

#: how the answer's arrays are named in messages
FIELD = "ANSWER"
#: the arrays an .npz answer may hold
NPZ_ARRAYS = ("u", "U", "sigma", "xi")
#: VTU points match the mesh's nodes within this share of the mesh extent ...
POINT_TOLERANCE = 1e-6
#: ... and within this share of its shortest edge
POINT_EDGE_SHARE = 0.1
#: the largest summary.json read beside a VTU answer (a solve's is a few KiB)
SUMMARY_LIMIT = 4 * 2**20
#: the first bytes of an .npz (a zip archive) and of a VTU (XML)
ZIP_MAGIC = b"PK\x03\x04"
XML_STARTS = (b"<?xml", b"<VTKFile")


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
