"""A directory of stored cases: content hashes, atomic case folders, a SQLite index.

Layout of a store ``DIR``::

    DIR/index.sqlite          one row per finished case (table ``cases``)
    DIR/cases/<id>/input.json the fully resolved input (its hash is the id)
    DIR/cases/<id>/mesh.npz   mesh points, cells and facet groups
    DIR/cases/<id>/solution.npz  sigma, xi, u, U, contact forces/pressures, flags
    DIR/cases/<id>/summary.json  elastoplast.certificate.solution.summary + the case's parameters
    DIR/cases/<id>/solution.vtu  for ParaView

A case id is the SHA-256 of its resolved input: the mesh arrays, the material,
boundary, obstacle and force, the method with the options given for it, and the
package version (a method's default tolerances belong to the version). Two
inputs that resolve alike (a 2D ``sphere`` and a ``cylinder``, an omitted key
and its default) get the same id.

Atomicity: a case folder is written under ``cases/.tmp-*`` and moved into place
by :func:`os.replace`; its index row is inserted (one SQLite transaction) only
after that. A folder without a row is invisible and is rewritten when the case
runs again; left-over temporary folders are removed when the store is opened
for writing.
"""

from __future__ import annotations

import dataclasses
import fcntl
import hashlib
import json
import os
import shutil
import sqlite3
import time
import uuid
from contextlib import closing, contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from elastoplast.version import __version__
from elastoplast.certificate.kkt import KKTResiduals
from elastoplast.certificate.solution import Solution, Status, make_solution
from elastoplast.errors import InputError
from elastoplast.fem.material import Material
from elastoplast.io.output import json_text, path_errors
from elastoplast.limits import shown
from elastoplast.mesh.base import Mesh
from elastoplast.problem.definition import Boundary, Obstacle, Problem

#: the index row of a case whose run raised (a crash, a lost worker): retried on resume
ERROR = "error"

KKT_FIELDS = tuple(f.name for f in dataclasses.fields(KKTResiduals))
SOLUTION_ARRAYS = ("sigma", "xi", "u", "contact_force", "contact_pressure", "active", "plastic")

_COLUMNS = [
    ("id", "TEXT PRIMARY KEY"),
    ("problem_id", "TEXT NOT NULL"),
    ("campaign", "TEXT"),
    ("params", "TEXT NOT NULL"),  # the sweep point as JSON: json_extract(params, '$."load.force"')
    ("method", "TEXT NOT NULL"),
    ("options", "TEXT NOT NULL"),
    ("status", "TEXT NOT NULL"),
    ("error", "TEXT"),
    ("dim", "INTEGER"),
    ("n_elements", "INTEGER"),
    ("n_nodes", "INTEGER"),
    ("force", "REAL"),
    ("E", "REAL"),
    ("nu", "REAL"),
    ("yield_stress", "REAL"),
    ("hardening", "REAL"),
    ("obstacle_shape", "TEXT"),
    ("obstacle_radius", "REAL"),
    ("U", "REAL"),
    ("kkt_worst", "REAL"),
    *[(f"kkt_{k}", "REAL") for k in KKT_FIELDS],
    ("duality_gap", "REAL"),
    # cases with an adaptive target: the final mesh's size and certified bounds
    ("final_elements", "INTEGER"),
    ("energy_lower", "REAL"),
    ("energy_upper", "REAL"),
    ("energy_gap_rel", "REAL"),
    ("U_lower", "REAL"),
    ("U_upper", "REAL"),
    ("bounds_certified", "INTEGER"),
    ("iterations", "INTEGER"),
    ("time_total", "REAL"),
    ("timings", "TEXT"),
    ("worker", "TEXT"),  # the Dask worker that ran the case
    ("version", "TEXT NOT NULL"),
    ("finished_at", "REAL NOT NULL"),
]
COLUMNS = tuple(name for name, _ in _COLUMNS)

#: what a store folder holds: its index, its case folders and its lock
INDEX_NAME = "index.sqlite"
STORE_FILES = frozenset({INDEX_NAME, "cases", ".lock"})


# ----------------------------------------------------------------------------
# the resolved input and its hash
# ----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class ResolvedInput:
    """Everything a case's result depends on, as JSON-able ``spec`` plus mesh ``arrays``.

    ``spec`` holds ``version``, ``method``, ``options``, ``force`` (for a loading
    path also ``path``, its forces) and the
    ``material``, ``boundary`` and ``obstacle`` fields; ``arrays`` the mesh
    ``points``, ``cells`` and one ``group:<name>`` per facet group.
    """

    spec: Mapping[str, Any]
    arrays: Mapping[str, np.ndarray]

    @property
    def case_id(self) -> str:
        return content_hash(self.spec, self.arrays)

    @property
    def problem_id(self) -> str:
        """The hash without method and options: cases of one problem share it."""
        return content_hash({k: v for k, v in self.spec.items() if k not in ("method", "options", "adapt")},
                            self.arrays)


def resolve(problem: Problem, method: str, options: Mapping[str, Any],
            adapt: Mapping[str, Any] | None = None) -> ResolvedInput:
    """The canonical form of ``(problem, method, options)`` and, for a case with an
    adaptive target, its ``adapt`` options (absent otherwise, so that the ids of
    ordinary cases do not change)."""
    mesh = problem.mesh
    arrays = {"points": np.ascontiguousarray(mesh.points, dtype=np.float64),
              "cells": np.ascontiguousarray(mesh.cells, dtype=np.int64)}
    for name in sorted(mesh.groups):
        arrays[f"group:{name}"] = np.ascontiguousarray(mesh.groups[name], dtype=np.int64)
    b = problem.boundary
    spec = {
        "version": __version__,
        "method": method,
        "options": {k: options[k] for k in sorted(options)},
        "force": float(problem.force),
        "material": dataclasses.asdict(problem.material),
        "boundary": {"clamped": list(b.clamped), "contact": list(b.contact),
                     "fix_component": {str(k): list(v) for k, v in sorted(b.fix_component.items())}},
        "obstacle": {"shape": problem.obstacle.shape, "dim": problem.obstacle.dim, "radius": problem.obstacle.radius,
                     "center": list(problem.obstacle.center), "expression": problem.obstacle.expression},
    }
    if problem.path is not None:  # a loading path (absent otherwise, so that Hencky cases keep their ids)
        spec["path"] = [float(f) for f in problem.path]
    if problem.obstacle.half_angle is not None:  # a cone (absent otherwise, as the path)
        spec["obstacle"]["half_angle"] = float(problem.obstacle.half_angle)
    if problem.axisymmetric:  # an axisymmetric model (absent otherwise, as the path)
        spec["axisymmetric"] = True
    if problem.displacement is not None:  # depth control (absent otherwise, as path)
        spec["displacement"] = float(problem.displacement)
    if problem.displacement_path is not None:
        spec["displacement_path"] = [float(d) for d in problem.displacement_path]
    if adapt is not None:
        spec["adapt"] = {k: adapt[k] for k in sorted(adapt)}
    return ResolvedInput(spec=json.loads(json.dumps(spec)), arrays=arrays)


def content_hash(spec: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> str:
    """SHA-256 of canonical JSON (sorted keys, floats by ``repr``) and the arrays'
    names, dtypes, shapes and bytes."""
    h = hashlib.sha256(json.dumps(spec, sort_keys=True, separators=(",", ":")).encode())
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(f"\n{name}:{a.dtype.str}:{a.shape}\n".encode())
        h.update(a.tobytes())
    return h.hexdigest()


def rebuild_problem(spec: Mapping[str, Any], arrays: Mapping[str, np.ndarray]) -> Problem:
    """The :class:`Problem` of a resolved input (validated when it was resolved)."""
    groups = {k.split(":", 1)[1]: np.asarray(v) for k, v in arrays.items() if k.startswith("group:")}
    mesh = Mesh(points=np.asarray(arrays["points"]), cells=np.asarray(arrays["cells"]), groups=groups)
    b, o = spec["boundary"], spec["obstacle"]
    return Problem(
        mesh=mesh,
        material=Material(**spec["material"]),
        boundary=Boundary(clamped=b["clamped"], contact=b["contact"],
                          fix_component={int(k): tuple(v) for k, v in b["fix_component"].items()}),
        obstacle=Obstacle(shape=o["shape"], dim=o["dim"], radius=o["radius"], center=tuple(o["center"]),
                          expression=o["expression"], half_angle=o.get("half_angle"),
                          axisymmetric=bool(spec.get("axisymmetric", False))),
        force=spec["force"],
        path=None if spec.get("path") is None else tuple(spec["path"]),
        axisymmetric=bool(spec.get("axisymmetric", False)),
        displacement=spec.get("displacement"),
        displacement_path=None if spec.get("displacement_path") is None else tuple(spec["displacement_path"]),
    )


# ----------------------------------------------------------------------------
# atomic files
# ----------------------------------------------------------------------------


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_file(path: Path, data: bytes) -> None:
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def atomic_write(path: str | Path, data: bytes) -> None:
    """Write ``path`` through a temporary file in the same folder and ``os.replace``."""
    path = Path(path)
    tmp = path.with_name(f".tmp-{path.name}-{uuid.uuid4().hex}")
    try:
        _write_file(tmp, data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    _fsync_dir(path.parent)


def _json_bytes(data: Any) -> bytes:
    return json_text(data).encode()  # strict JSON, as in summary.json


def _npz_bytes(arrays: Mapping[str, np.ndarray]) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


# ----------------------------------------------------------------------------
# the store
# ----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class CaseRecord:
    """What a finished case writes: its files (name -> bytes) and its index row."""

    files: Mapping[str, bytes]
    row: Mapping[str, Any]


def case_record(inp: ResolvedInput, params: Mapping[str, Any], campaign: str, *, solution: Solution | None = None,
                summary: Mapping[str, Any] | None = None, vtu: bytes | None = None, error: str | None = None,
                traceback: str | None = None, worker: str | None = None, files: Mapping[str, bytes] | None = None,
                bounds: Mapping[str, Any] | None = None) -> CaseRecord:
    """The files and index row of a case: a solver outcome (``solution``, its
    ``summary`` and ``vtu``; an adaptive case adds its ``files`` and ``bounds``) or
    an ``error`` (one line; the ``traceback`` goes to ``summary.json``)."""
    spec = inp.spec
    extra_files = dict(files or {})
    mesh_points, mesh_cells = inp.arrays["points"], inp.arrays["cells"]
    head = {"case": inp.case_id, "problem_id": inp.problem_id, "campaign": campaign, "params": dict(params)}
    files = {"input.json": _json_bytes({**head, "input": spec}), "mesh.npz": _npz_bytes(inp.arrays)}
    row: dict[str, Any] = {
        "id": inp.case_id, "problem_id": inp.problem_id, "campaign": campaign,
        "params": json.dumps(dict(params), sort_keys=True), "method": spec["method"],
        "options": json.dumps(spec["options"], sort_keys=True), "dim": mesh_points.shape[1],
        "n_elements": mesh_cells.shape[0], "n_nodes": mesh_points.shape[0], "force": spec["force"],
        **{k: spec["material"][k] for k in ("E", "nu", "yield_stress", "hardening")},
        "obstacle_shape": spec["obstacle"]["shape"], "obstacle_radius": spec["obstacle"]["radius"],
        "worker": worker, "version": spec["version"], "finished_at": time.time(),
    }
    if solution is None:
        files["summary.json"] = _json_bytes({**head, "status": ERROR, "error": error, "traceback": traceback})
        row.update(status=ERROR, error=error)
        return CaseRecord(files=files, row=row)
    sol = solution
    files["solution.npz"] = _npz_bytes({**{k: getattr(sol, k) for k in SOLUTION_ARRAYS}, "U": np.float64(sol.U)})
    files["summary.json"] = _json_bytes({**head, **summary})
    if vtu is not None:
        files["solution.vtu"] = vtu
    files.update(extra_files)
    if bounds is not None:
        row.update({k: bounds[k] for k in ("final_elements", "energy_lower", "energy_upper", "energy_gap_rel",
                                           "U_lower", "U_upper")}, bounds_certified=int(bool(bounds["bounds_certified"])))
    row.update(status=sol.status.value, error=None if sol.converged else sol.message, U=sol.U,
               kkt_worst=sol.kkt.worst, **{f"kkt_{k}": v for k, v in sol.kkt.as_dict().items()},
               duality_gap=sol.duality_gap, iterations=sol.iterations, time_total=sol.time_s,
               timings=json.dumps(sol.timings, sort_keys=True))
    return CaseRecord(files=files, row=row)


class Store:
    """A store directory (see the module docstring). Reading needs no lock;
    :meth:`writer` holds an exclusive lock for one campaign at a time."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        try:  # 'nosuch/../DIR' is DIR, judged and written as DIR
            self.path = self.path.expanduser().resolve()
        except (OSError, ValueError, RuntimeError):  # a name too long, a loop: refused where the path is used
            pass

    @property
    def index_path(self) -> Path:
        return self.path / INDEX_NAME

    def case_dir(self, case_id: str) -> Path:
        return self.path / "cases" / case_id

    def _connect(self) -> sqlite3.Connection:
        con = sqlite3.connect(self.index_path, timeout=30.0)
        con.row_factory = sqlite3.Row
        return con

    @contextmanager
    def _readable(self, what: str) -> Iterator[None]:
        """Turn a damaged store (not SQLite, missing or garbled case files) into an InputError."""
        try:
            yield
        except InputError:
            raise
        except (sqlite3.DatabaseError, OSError, ValueError, KeyError, EOFError) as exc:
            raise InputError("store", f"{shown(self.path)} is damaged: cannot read {what} "
                                      f"({type(exc).__name__}: {exc})") from None

    @contextmanager
    def _writable(self) -> Iterator[None]:
        """A write the file system refuses (a full disk, a file-size limit: sqlite's "disk
        I/O error"; a read-only folder) is the place written to, ``out``, not a damaged store."""
        try:
            yield
        except sqlite3.OperationalError as exc:
            if "disk" not in str(exc) and "readonly" not in str(exc):
                raise
            raise InputError("out", f"cannot write the store {shown(self.path)}: {exc}") from None

    # -- reading ----------------------------------------------------------------

    def exists(self) -> bool:
        with path_errors(self.path, "store"):  # a name too long for the file system, a NUL byte
            return self.index_path.is_file()

    def rows(self, where: str = "", params: tuple = ()) -> list[dict[str, Any]]:
        """Index rows as dicts, e.g. ``rows("status = ? AND method = ?", ("converged", "conic"))``."""
        if not self.exists():
            return []
        sql = "SELECT * FROM cases" + (f" WHERE {where}" if where else "") + " ORDER BY finished_at, id"
        with self._readable(self.index_path.name), closing(self._connect()) as con:
            return [dict(r) for r in con.execute(sql, params)]

    def row(self, case_id: str) -> dict[str, Any]:
        found = self.rows("id = ?", (case_id,))
        if not found:
            raise InputError("case", f"no case {case_id!r} in {shown(self.path)}")
        return found[0]

    def load_input(self, case_id: str) -> ResolvedInput:
        """The stored resolved input; refuses a case whose files do not hash to its id."""
        folder = self.case_dir(case_id)
        with self._readable(f"the input of case {case_id}"):
            spec = json.loads((folder / "input.json").read_text())["input"]
            with np.load(folder / "mesh.npz") as z:
                arrays = {k: z[k] for k in z.files}
        inp = ResolvedInput(spec=spec, arrays=arrays)
        if inp.case_id != case_id:
            raise InputError("case", f"{folder} does not hash to its id (files changed after the run)")
        return inp

    def load_problem(self, case_id: str, *, final: bool = True) -> Problem:
        """The case's problem; for a case with an adaptive target, on the final
        adapted mesh (the one its solution lives on) unless ``final`` is False."""
        from dataclasses import replace

        inp = self.load_input(case_id)
        problem = rebuild_problem(inp.spec, inp.arrays)
        adapted = self.case_dir(case_id) / "adapted.msh"
        if final and adapted.is_file():
            from elastoplast.mesh.base import read_mesh

            with self._readable(f"the adapted mesh of case {case_id}"):
                problem = replace(problem, mesh=read_mesh(adapted))
        return problem

    def load_solution(self, case_id: str, disc=None, *, recertify: bool = False) -> Solution:
        """The stored case as a :class:`Solution`.

        By default it is rebuilt exactly as stored: arrays from ``solution.npz``,
        the KKT residuals, objective values, iterations, timings and history from
        ``summary.json``. With ``recertify=True`` it goes through
        :func:`~elastoplast.certificate.solution.make_solution`, which recomputes the
        certificate and the derived fields from the arrays (needs ``disc``, or
        discretises the stored problem).
        """
        row = self.row(case_id)
        if row["status"] == ERROR:
            raise InputError("case", f"case {case_id} has no solution: its run raised ({row['error']})")
        folder = self.case_dir(case_id)
        with self._readable(f"the solution of case {case_id}"):
            data = json.loads((folder / "summary.json").read_text())
            with np.load(folder / "solution.npz") as z:
                arr = {k: z[k] for k in z.files}
        if recertify:
            from elastoplast.fem.discretize import discretize

            if "path" in data:
                raise InputError("case", f"case {case_id} is a loading path: its solution is the last step's, "
                                         "certified by that step's problem, not by Hencky's (solve the path again)")

            disc = disc if disc is not None else discretize(self.load_problem(case_id))
            return make_solution(disc, method=data["method"], status=Status(data["status"]), sigma=arr["sigma"],
                                 xi=arr["xi"], u_free=disc.free_displacement(arr["u"]), U=float(arr["U"]),
                                 contact_force=arr["contact_force"], iterations=data["iterations"],
                                 timings=data["timings"], message=data["message"], history=data.get("history"))
        if set(data["kkt"]) != set(KKT_FIELDS):
            raise InputError("case", f"case {case_id} was certified with other KKT residuals {sorted(data['kkt'])} "
                             f"(this version has {list(KKT_FIELDS)}): load it with recertify=True")
        return Solution(
            method=data["method"], status=Status(data["status"]), sigma=arr["sigma"], xi=arr["xi"], u=arr["u"],
            U=float(arr["U"]), contact_force=arr["contact_force"], contact_pressure=arr["contact_pressure"],
            active=arr["active"], plastic=arr["plastic"], kkt=KKTResiduals(**data["kkt"]),
            duality_gap=data["duality_gap"], value_S=data["value_S"], value_D=data["value_D"],
            iterations=data["iterations"], timings=data["timings"], message=data["message"],
            history=data.get("history", []),
        )

    def load_path(self, case_id: str) -> list[dict[str, Any]] | None:
        """The steps of a loading-path case (``summary.json``'s ``"path"``, one entry per
        step in order); None for a case without a path."""
        with self._readable(f"the summary of case {case_id}"):
            data = json.loads((self.case_dir(case_id) / "summary.json").read_text())
        return data.get("path")

    # -- writing ----------------------------------------------------------------

    @contextmanager
    def writer(self) -> Iterator["Store"]:
        """Lock the store, create the index if needed and sweep temporary folders."""
        with path_errors(self.path, "out"):
            exists, is_dir = self.path.exists(), self.path.is_dir()
            names = {p.name for p in self.path.iterdir()} if is_dir else set()
        if exists and not is_dir:
            raise InputError("out", f"{shown(self.path)} exists and is not a folder")
        if is_dir and not self.exists() and names - (STORE_FILES - {INDEX_NAME}):
            raise InputError("out", f"{shown(self.path)} is not empty and holds no campaign store (no index.sqlite)")
        try:
            (self.path / "cases").mkdir(parents=True, exist_ok=True)
            lock = open(self.path / ".lock", "w")
        except OSError as exc:
            raise InputError("out", f"cannot write the store {shown(self.path)}: {exc.strerror}") from None
        try:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise InputError("out", f"another process is writing to {shown(self.path)}") from None
            for tmp in (self.path / "cases").glob(".tmp-*"):
                shutil.rmtree(tmp, ignore_errors=True)
            cols = ", ".join(f'"{n}" {t}' for n, t in _COLUMNS)
            with self._readable(self.index_path.name), self._writable(), closing(self._connect()) as con, con:
                con.execute(f"CREATE TABLE IF NOT EXISTS cases ({cols})")
                have = {r["name"] for r in con.execute("PRAGMA table_info(cases)")}
                for n, t in _COLUMNS:  # columns a newer version added (e.g. a new KKT residual)
                    if n not in have:
                        con.execute(f'ALTER TABLE cases ADD COLUMN "{n}" {t.replace(" PRIMARY KEY", "").replace(" NOT NULL", "")}')
            yield self
        finally:
            lock.close()

    def add(self, record: CaseRecord) -> None:
        """Write the case folder atomically, then its index row (replacing an older one)."""
        case_id = record.row["id"]
        final = self.case_dir(case_id)
        tmp = final.with_name(f".tmp-{case_id}-{uuid.uuid4().hex}")
        tmp.mkdir()
        for name, data in record.files.items():
            _write_file(tmp / name, data)
        _fsync_dir(tmp)
        if final.exists():  # a folder without a row (a crash before indexing) or a retried error
            old = final.with_name(f".tmp-old-{case_id}-{uuid.uuid4().hex}")
            os.replace(final, old)
            shutil.rmtree(old)
        os.replace(tmp, final)
        _fsync_dir(final.parent)
        names = [n for n in COLUMNS if n in record.row]
        quoted = ", ".join(f'"{n}"' for n in names)
        sql = f"INSERT OR REPLACE INTO cases ({quoted}) VALUES ({', '.join('?' * len(names))})"
        with closing(self._connect()) as con, con:
            con.execute(sql, [record.row[n] for n in names])
