"""Writing results: ``solution.vtu`` for ParaView, ``summary.json`` and, for iterative
methods, ``convergence.png``."""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from elastoplast.certificate.solution import Solution
from elastoplast.errors import InputError
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import von_mises
from elastoplast.limits import shown

_VTK_CELL = {2: "triangle", 3: "tetra"}


def mandel_to_tensor(sigma: np.ndarray) -> np.ndarray:
    """Mandel vectors ``(n, 4|6)`` to full symmetric tensors ``(n, 3, 3)``."""
    n = sigma.shape[0]
    t = np.zeros((n, 3, 3))
    r = 1.0 / np.sqrt(2.0)
    for i in range(3):
        t[:, i, i] = sigma[:, i]
    if sigma.shape[1] == 4:
        t[:, 0, 1] = t[:, 1, 0] = r * sigma[:, 3]
    else:
        t[:, 1, 2] = t[:, 2, 1] = r * sigma[:, 3]
        t[:, 0, 2] = t[:, 2, 0] = r * sigma[:, 4]
        t[:, 0, 1] = t[:, 1, 0] = r * sigma[:, 5]
    return t


_VTK_FACET = {2: "line", 3: "triangle"}


def write_vtu(path: str | Path, disc: Discretization, sol: Solution, cell_data: dict[str, np.ndarray] | None = None,
              facets: tuple[np.ndarray, dict[str, np.ndarray]] | None = None) -> None:
    """Displacement, contact pressure/force (nodal); stress tensor, von Mises,
    xi and the plastic flag (per element); ``cell_data``: more per-element arrays.

    ``facets = (nodes (n_f, d), {name: values (n_f,)})`` adds a second block of
    boundary facets (lines in 2D, triangles in 3D) carrying their own arrays;
    every array is then defined on both blocks, NaN where it does not apply.
    """
    import meshio

    mesh = disc.mesh
    d = disc.dim
    points = mesh.points if d == 3 else np.column_stack([mesh.points, np.zeros(mesh.n_nodes)])
    disp = sol.u if d == 3 else np.column_stack([sol.u, np.zeros(mesh.n_nodes)])
    pressure = np.zeros(mesh.n_nodes)
    pressure[disc.contact_nodes] = np.nan_to_num(sol.contact_pressure)
    force = np.zeros(mesh.n_nodes)
    force[disc.contact_nodes] = sol.contact_force
    cells = {
        "stress": mandel_to_tensor(sol.sigma).reshape(-1, 9),
        "von_mises": von_mises(sol.sigma),
        "xi": sol.xi,
        "plastic": sol.plastic.astype(np.int32),
        **(cell_data or {}),
    }
    blocks = [(_VTK_CELL[d], mesh.cells)]
    data = {k: [v] for k, v in cells.items()}
    if facets is not None:
        nodes, values = facets
        blocks.append((_VTK_FACET[d], np.asarray(nodes)))
        data = {}
        for name in [*cells, *(k for k in values if k not in cells)]:
            el = np.asarray(cells[name], dtype=float) if name in cells else np.full(mesh.n_elements, np.nan)
            on_f = values.get(name)
            f = np.asarray(on_f, dtype=float) if on_f is not None else np.full((len(nodes),) + el.shape[1:], np.nan)
            data[name] = [el, f]
    meshio.write(
        Path(path),
        meshio.Mesh(
            points,
            blocks,
            point_data={"displacement": disp, "contact_pressure": pressure, "contact_force": force},
            cell_data=data,
        ),
    )


#: written into every output folder (with the provenance stamp): a folder holding it
#: is elastoplast's to replace
OUTPUT_MARKER = ".elastoplast-output.json"
#: what earlier versions wrote, before the marker existed
LEGACY_OUTPUTS = frozenset({"summary.json", "solution.vtu", "convergence.png", "report.md", "compare.json", "compare.png"})


#: errors writing the output that only the place written to can cause (disk full, over quota, read-only,
#: a file larger than the file system or the process's file-size limit allows)
WRITE_TARGET_ERRORS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EFBIG})


@contextlib.contextmanager
def path_errors(path: str | Path, field: str) -> Iterator[None]:
    """Turn an error looking at a path the user gave (a name too long for the file
    system, a NUL byte, a folder that may not be searched, an unknown ``~user``, no path
    at all) into an
    :class:`InputError` naming ``field``, the path shortened."""
    try:
        yield
    except InputError:
        raise
    except (OSError, ValueError, TypeError, RuntimeError) as exc:
        reason = getattr(exc, "strerror", None) or exc
        raise InputError(field, f"cannot use {shown(path)}: {reason}") from None


def check_output_dir(out_dir: str | Path, field: str = "out") -> Path:
    """Refuse, before any work, an output folder that cannot receive results.

    It may not exist yet (it is created, with its parents), or be empty, or
    hold an earlier elastoplast output (which the new run replaces whole). A
    file, a folder with other files, the working directory itself or one of
    its ancestors, a path the file system refuses (a name too long) and a place
    where nothing can be written are refused.
    """
    cwd = Path.cwd().resolve()
    with path_errors(out_dir, field):
        # resolved before any test: 'nosuch/../DIR' is DIR once nosuch exists, and must be judged as DIR
        out = Path(out_dir).expanduser().resolve()
        exists, is_dir = out.exists(), out.is_dir()
        names = sorted(p.name for p in out.iterdir()) if is_dir else []
        inside = exists and (out.resolve() == cwd or out.resolve() in cwd.parents)
        ancestor = out.parent
        while not ancestor.exists():
            ancestor = ancestor.parent
        ancestor_is_dir = ancestor.is_dir()
    if exists and not is_dir:
        raise InputError(field, f"{shown(out_dir)} exists and is not a folder")
    if inside:
        raise InputError(field, f"{shown(out_dir)} is the working directory or contains it; name a subfolder")
    if names and OUTPUT_MARKER not in names and not set(names) <= LEGACY_OUTPUTS:
        listed = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
        raise InputError(field, f"{shown(out_dir)} holds files elastoplast did not write ({listed}); "
                                "name a new or empty folder")
    if not ancestor_is_dir:
        raise InputError(field, f"cannot create {shown(out_dir)}: {shown(ancestor)} is not a folder")
    try:  # the only sure test of writability is to write
        os.rmdir(tempfile.mkdtemp(prefix=".elastoplast-probe-", dir=ancestor))
    except OSError as exc:
        raise InputError(field, f"cannot create {shown(out_dir)}: {shown(ancestor)} is not writable "
                                f"({exc.strerror})") from None
    return out


def current_umask() -> int:
    """The process's umask, read without changing it (``/proc/self/status``; where
    that is missing, set and restored at once, which other threads could see)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


@contextlib.contextmanager
def staged_output(out_dir: str | Path, field: str = "out") -> Iterator[Path]:
    """A fresh folder to write a run's files into, put in place of ``out_dir`` at the end.

    The files appear together: they are written beside ``out_dir`` under a
    temporary name, and renamed into place when the block ends without an
    exception (an earlier output in ``out_dir`` is moved aside first and then
    deleted, so the folder holds only the new run's files). On an exception
    the temporary folder is removed and ``out_dir`` is left as it was.
    """
    from elastoplast.io.provenance import stamp

    out = check_output_dir(out_dir, field)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
        os.chmod(tmp, 0o777 & ~current_umask())  # mkdtemp's 0700 would keep the results from the user's group
    except OSError as exc:
        raise InputError(field, f"cannot create {out_dir}: {exc.strerror}") from None
    try:
        yield tmp
        (tmp / OUTPUT_MARKER).write_text(json_text({"provenance": stamp()}))
        if out.exists():
            ours = {p.name for p in out.iterdir()}  # judged again: the folder may have changed since the check
            if ours and OUTPUT_MARKER not in ours and not ours <= LEGACY_OUTPUTS:
                raise InputError(field, f"{shown(out_dir)} now holds files elastoplast did not write; nothing "
                                        "was replaced")
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            os.replace(out, old / out.name)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        # the place, not the program: name it (unless the error names a file elsewhere)
        elsewhere = exc.filename is not None and not Path(exc.filename).absolute().is_relative_to(out.parent)
        if exc.errno in WRITE_TARGET_ERRORS and not elsewhere:
            raise InputError(field, f"cannot write {out_dir}: {exc.strerror}") from None
        raise
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def json_default(obj: Any) -> Any:
    """JSON for numpy scalars and arrays (summary.json, the campaign store)."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot write {type(obj).__name__} to JSON")


def strict(obj: Any) -> Any:
    """``obj`` with numpy values made plain and every NaN or infinity made ``None``:
    JSON has no NaN (``json.dumps`` would write ``NaN``, which strict readers refuse)."""
    if isinstance(obj, dict):
        return {str(k): strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    if isinstance(obj, (np.ndarray, np.generic)):
        return strict(json_default(obj))
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(data: Any) -> str:
    """Strict JSON text (no NaN, no Infinity), indented, ending in a newline."""
    return json.dumps(strict(data), indent=2, allow_nan=False) + "\n"
