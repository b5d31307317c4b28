"""The files of :func:`elastoplast.io.export.export`: where they may go, how they are written, how they are read back.

An exported program is a pair, ``OUT`` and its sidecar ``OUT.json``. Before any work
:func:`check_export_path` refuses (``InputError`` naming the caller's field: ``path``
from Python, ``--out`` on the command line) what cannot receive the pair: no path at
all, a name ending in a separator or naming a folder, a missing parent folder, the
problem file or its mesh file (``protect``, compared with :func:`os.path.samefile`),
a device or other non-regular file, an existing file that is not a previous export of
elastoplast (one whose sidecar names it and holds its SHA-256; such a pair is replaced),
a suffix naming the other format (``.npz`` for CBF, ``.cbf`` for npz; field
``format``), and a folder nothing can be written into. :func:`write_pair` writes both
files under temporary names in the same folder and renames them into place together,
so no half pair is ever left; a full disk, a read-only file system, a denied permission
and the like are ``InputError`` naming the field, and every temporary is removed on
any error.

:func:`read_sidecar` and :func:`load_npz` read the pair back, refusing what is not
one with an ``InputError`` naming ``path``.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import stat
import tempfile
import zipfile
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np
import scipy.sparse as sp

from elastoplast.errors import InputError
from elastoplast.io.output import WRITE_TARGET_ERRORS, current_umask, path_errors
from elastoplast.limits import as_path, check_input_file, read_bytes, shown

SIDECAR_SUFFIX = ".json"
#: the suffix each format's files have (the other one's is refused)
SUFFIXES = {"cbf": ".cbf", "npz": ".npz"}
#: the largest sidecar read back (the free dofs and contact nodes are listed in it)
MAX_SIDECAR_BYTES = 2**30
#: the largest npz read back
MAX_NPZ_BYTES = 16 * 2**30
#: errors writing the pair that only the place written to can cause
WRITE_ERRORS = WRITE_TARGET_ERRORS | {errno.EACCES, errno.EPERM, errno.EISDIR, errno.ENOTDIR, errno.ENAMETOOLONG,
                                      errno.ELOOP, errno.ENOENT, errno.EXDEV, errno.ETXTBSY}
_TMP_PREFIX = ".elastoplast-export-"


def sidecar_path(path: str | Path) -> Path:
    """``OUT.json`` beside ``OUT``."""
    path = Path(path)
    return path.with_name(path.name + SIDECAR_SUFFIX)


def _lstat(path: Path) -> os.stat_result | None:
    try:
        return os.lstat(path)
    except FileNotFoundError:
        return None


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(2**20), b""):
            h.update(chunk)
    return h.hexdigest()


def _our_sidecar(side: Path, name: str) -> dict[str, Any] | None:
    """The sidecar ``side`` if it is one elastoplast wrote for a file called ``name``."""
    try:
        meta = json.loads(read_bytes(side, "sidecar", "sidecar", MAX_SIDECAR_BYTES).decode("utf-8"))
    except (InputError, UnicodeDecodeError, ValueError, RecursionError):
        return None
    ok = (isinstance(meta, dict) and meta.get("file") == name and meta.get("format") in SUFFIXES
          and "elastoplast_version" in meta and isinstance(meta.get("sha256"), str))
    return meta if ok else None


def previous_export(path: Path) -> bool:
    """Whether ``path`` is a file elastoplast exported: its sidecar names it and holds its SHA-256."""
    st = _lstat(path)
    if st is None or not stat.S_ISREG(st.st_mode):
        return False
    meta = _our_sidecar(sidecar_path(path), path.name)
    return meta is not None and meta["sha256"] == _sha256(path)


def check_export_path(path, format: str, field: str = "path", protect: Iterable[str | Path] = ()) -> Path:
    """``path`` as a :class:`Path` that may receive an export in ``format`` and its sidecar,
    or an ``InputError`` naming ``field`` (``format`` for a suffix of the other format).
    ``protect``: files never to be written over (the problem file, its mesh file)."""
    as_path(path, field, "output file")  # no path at all: refused naming the field
    with path_errors(path, field):
        text = os.fsdecode(os.fspath(path))  # the text as given: Path() would drop a final separator
    if not text:
        raise InputError(field, "an empty path names no file")
    if text.endswith(tuple(s for s in (os.sep, os.altsep) if s)) or Path(text).name in ("", ".", ".."):
        raise InputError(field, f"{shown(text)} names a folder; name the file to write (e.g. problem.cbf)")
    path = Path(text)
    for fmt, suffix in SUFFIXES.items():
        if fmt != format and path.suffix.lower() == suffix:
            raise InputError("format", f"the output file {shown(path)} ends in {suffix}, but the format asked for is "
                                       f"{format} (cbf unless told otherwise): ask for format {fmt}, or name a "
                                       f"{SUFFIXES.get(format, '')} file")
    side = sidecar_path(path)
    with path_errors(path, field):
        parent = path.parent
        st_parent = os.stat(parent)
        if not stat.S_ISDIR(st_parent.st_mode):
            raise InputError(field, f"{shown(parent)} is not a folder")
        found = {target: _lstat(target) for target in (path, side)}
        protected = [Path(p) for p in protect if p is not None and os.path.exists(p)]
        for target, st in found.items():
            if st is None:
                continue
            if target.is_dir():  # followed through a symbolic link too
                raise InputError(field, f"{shown(target)} is a folder; name a file")
            for p in protected:
                if target.exists() and os.path.samefile(target, p):
                    raise InputError(field, f"{shown(target)} is the problem's own file {shown(p)}; name another "
                                            "output file")
            if stat.S_ISLNK(st.st_mode) and not target.exists():
                raise InputError(field, f"{shown(target)} is a broken symbolic link; name another output file")
            if not stat.S_ISREG(os.stat(target).st_mode):
                raise InputError(field, f"{shown(target)} is not a regular file (a device, pipe or socket cannot "
                                        "hold an export)")
        if found[path] is not None and not previous_export(path):
            raise InputError(field, f"{shown(path)} exists and is not an earlier export of elastoplast (no "
                                    f"{side.name} beside it naming it with its SHA-256): nothing is written over "
                                    "it; remove it or name a new file")
        if found[path] is None and found[side] is not None and _our_sidecar(side, path.name) is None:
            raise InputError(field, f"{shown(side)} exists and is not the map back of an earlier export: nothing "
                                    "is written over it; remove it or name a new file")
        # the only sure test of writability is to write
        fd, probe = tempfile.mkstemp(prefix=_TMP_PREFIX, suffix=".probe", dir=parent)
        os.close(fd)
        os.unlink(probe)
    return path


def _write_all(fd: int, data: bytes) -> None:
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


@contextlib.contextmanager
def _write_errors(path: Path, field: str) -> Iterator[None]:
    try:
        yield
    except OSError as exc:
        if exc.errno in WRITE_ERRORS:
            raise InputError(field, f"cannot write {shown(path)}: {exc.strerror or exc}") from None
        raise


def write_pair(path: Path, data: bytes, sidecar_text: str, field: str = "path") -> Path:
    """Write ``data`` to ``path`` and ``sidecar_text`` to its sidecar, both or neither:
    each to a temporary file in the same folder, then renamed into place. Returns the
    sidecar's path."""
    side = sidecar_path(path)
    temps: list[str] = []
    placed: list[Path] = []
    try:
        with _write_errors(path, field):
            mode = 0o666 & ~current_umask()
            for content in (data, sidecar_text.encode("utf-8")):
                fd, tmp = tempfile.mkstemp(prefix=_TMP_PREFIX, suffix=".tmp", dir=path.parent)
                temps.append(tmp)
                os.fchmod(fd, mode)
                _write_all(fd, content)
            for tmp, target in zip(temps, (path, side)):
                os.replace(tmp, target)
                placed.append(target)
    except BaseException:
        for tmp in temps:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        if len(placed) == 1:  # the new file without its map back: neither stays (the old pair was replaceable)
            for target in (path, side):
                with contextlib.suppress(OSError):
                    os.unlink(target)
        raise
    return side


# ----------------------------------------------------------------------------
# reading back
# ----------------------------------------------------------------------------


def read_sidecar(path: str | Path) -> dict[str, Any]:
    """The sidecar of an exported file (``path`` is the file or its ``.json``); an
    ``InputError`` naming ``path`` when it is missing, unreadable or not a sidecar."""
    path = as_path(path, "path", "exported file or its sidecar")
    side = path if path.suffix == SIDECAR_SUFFIX else sidecar_path(path)
    raw = read_bytes(side, "path", "sidecar", MAX_SIDECAR_BYTES)
    try:
        meta = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError("path", f"{shown(side)} is not a sidecar of an export (not JSON: {exc})") from None
    needed = ("form", "format", "variables", "rows", "units", "mesh", "duals")
    if not isinstance(meta, dict) or any(key not in meta for key in needed):
        raise InputError("path", f"{shown(side)} is not a sidecar of an export (it lacks "
                                 f"{', '.join(k for k in needed if not isinstance(meta, dict) or k not in meta)})")
    return meta


def load_npz(path: str | Path) -> dict[str, Any]:
    """An exported ``.npz`` as ``P, q, A, b`` (CSC) and SCS's cone dictionary ``cones``
    (``z``, ``l``, ``q``); an ``InputError`` naming ``path`` for anything else."""
    path = as_path(path, "path", "exported npz file")
    size = check_input_file(path, "path", "exported npz file")
    if size > MAX_NPZ_BYTES:
        raise InputError("path", f"{shown(path)} has {size} bytes, more than an exported npz file may have")
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise InputError("path", f"cannot read {shown(path)}: {exc.strerror or exc}") from None
    if magic != b"PK\x03\x04":
        raise InputError("path", f"{shown(path)} is not an npz file (not a zip archive; a CBF export is read with "
                                 "read_cbf)")
    try:
        with np.load(path, allow_pickle=False) as f:
            mats = {name: sp.csc_matrix((f[f"{name}_data"], f[f"{name}_indices"], f[f"{name}_indptr"]),
                                        shape=tuple(int(v) for v in f[f"{name}_shape"])) for name in ("A", "P")}
            cones = {"z": int(f["zero"]), "l": int(f["nonnegative"]), "q": [int(v) for v in f["second_order"]]}
            return {**mats, "q": np.array(f["q"]), "b": np.array(f["b"]), "cones": cones}
    except (KeyError, ValueError, TypeError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError("path", f"{shown(path)} is not an exported npz file ({type(exc).__name__}: {exc})") from None
