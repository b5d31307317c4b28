"""Limits on what the input may cost: readable files of bounded size, and memory estimated before anything is allocated.

Every check raises :class:`~elastoplast.errors.InputError` naming the field the user wrote, with a one-line
message; nothing here allocates before the memory checks have passed."""

from __future__ import annotations

import ctypes
import math
import os
import re
import resource
import stat
from functools import lru_cache
from pathlib import Path
from typing import Sequence

from elastoplast.errors import InputError, elide

# Bytes per element of the mesh and discretisation build at its peak (measured, see
# discretization_bytes)
_BUILD_BYTES_PER_ELEMENT = {2: 770, 3: 1650}
# meshio's peak while reading, per byte of file, by suffix (measured, see mesh_read_bytes)
MESH_READ_FACTORS = {".msh": 8, ".vtk": 4, ".vtu": 16}
MESH_READ_DEFAULT_FACTOR = 16
# An element count beyond any machine, refused without further arithmetic.
MAX_ELEMENTS = 2**40


def blocks(n: int, size: int):
    """Consecutive slices of at most ``size`` that cover ``range(n)``: the blocks in which an
    operation over ``n`` rows bounds its temporaries."""
    return (slice(lo, min(n, lo + size)) for lo in range(0, n, size))


def release_freed_memory() -> None:
    """Hand the free pages of the C heap back to the system (glibc's ``malloc_trim``; nothing
    where there is no glibc).

    After numpy has freed a few large temporaries, glibc raises its threshold for serving large
    blocks from their own mappings, and the next ones come from the heap. Freed there, their pages
    stay resident. A computation in phases then has a resident peak well above what it uses at
    any time: 100 to 200 MB at 98,304 tetrahedra for the local lower bound, which calls this
    between its phases (Dask's workers trim their heap the same way)."""
    trim = malloc_trim()
    if trim is not None:
        trim(0)


@lru_cache(maxsize=1)
def malloc_trim():
    """glibc's ``malloc_trim``, or None."""
    try:
        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):
        return None


def shown(path: Path) -> str:
    """A path for a one-line message (very long ones cut in the middle)."""
    return elide(str(path), 200)


def as_path(path, field: str, what: str) -> Path:
    """``path`` as a :class:`Path`, or an InputError naming ``field`` when it is no path at all."""
    if not isinstance(path, (str, os.PathLike)):
        raise InputError(field, f"expected a path to {a_or_an(what)}, got {type(path).__name__}")
    return Path(path)


def a_or_an(word: str) -> str:
    """``word`` with its indefinite article: ``a problem file``, ``an answer file``."""
    return f"{'an' if word[:1].lower() in 'aeiou' else 'a'} {word}"


def check_input_file(path: Path, field: str, what: str) -> int:
    """The size in bytes of ``path``, refusing what cannot be read as a file.

    Refused: a missing path, a directory, anything but a regular file (a FIFO or a
    device would block or never end), a file without read permission, an empty file.
    """
    try:
        st = path.stat()
    except (FileNotFoundError, NotADirectoryError):
        raise InputError(field, f"{what} not found: {shown(path)}") from None
    except ValueError:  # a NUL byte in the path
        raise InputError(field, f"invalid path {shown(path)!r}") from None
    except OSError as exc:
        raise InputError(field, f"cannot access {what} {shown(path)}: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(field, f"{shown(path)} is a directory, not {a_or_an(what)}")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(field, f"{shown(path)} is not a regular file (a device, pipe or socket cannot be "
                                f"{a_or_an(what)})")
    if not os.access(path, os.R_OK):
        raise InputError(field, f"{what} {shown(path)} cannot be read (permission denied)")
    if st.st_size == 0:
        raise InputError(field, f"{what} {shown(path)} is empty")
    return int(st.st_size)


def read_bytes(path: Path, field: str, what: str, limit: int) -> bytes:
    """The contents of ``path`` (at most ``limit`` bytes, else refused)."""
    size = check_input_file(path, field, what)
    if size > limit:
        raise InputError(field, f"{what} {path} has {format_bytes(size)}, more than the {format_bytes(limit)} "
                                f"{a_or_an(what)} may have")
    try:
        with open(path, "rb") as fh:
            return fh.read(limit + 1)
    except OSError as exc:
        raise InputError(field, f"cannot read {what} {path}: {exc.strerror or exc}") from None


MEMORY_ENV = "ELASTOPLAST_MEMORY_LIMIT"


_BYTE_UNITS = {"": 1, "k": 2**10, "m": 2**20, "g": 2**30, "t": 2**40, "p": 2**50}


def format_bytes(n: float) -> str:
    """``1536 -> '1.5 KiB'``."""
    for unit, size in (("PiB", 2**50), ("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def parse_bytes(text: str, field: str = MEMORY_ENV) -> int:
    """``'512M'``, ``'4 GiB'``, ``'1.5g'``, ``'1000000'`` -> bytes (binary units)."""
    m = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]*)?(?:e[+-]?[0-9]+)?)\s*([kmgtp]?)(?:i?b)?\s*", str(text).lower())
    if m is None:
        raise InputError(field, f"must be a size such as 4G, 512M or 1000000 (bytes), got {text!r}")
    value = float(m.group(1)) * _BYTE_UNITS[m.group(2)]
    if not (math.isfinite(value) and value >= 1):
        raise InputError(field, f"must be a positive size, got {text!r}")
    return int(value)


def _read_int(path: str) -> int | None:
    try:
        with open(path) as fh:
            text = fh.read().strip()
    except OSError:
        return None
    return int(text) if text.isdigit() else None


def _meminfo_available() -> int | None:
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def _cgroup_room() -> int | None:
    """Room left under a cgroup memory limit (v2, then v1), if there is one."""
    for limit_file, usage_file in (("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory.current"),
                                   ("/sys/fs/cgroup/memory/memory.limit_in_bytes",
                                    "/sys/fs/cgroup/memory/memory.usage_in_bytes")):
        limit, usage = _read_int(limit_file), _read_int(usage_file)
        if limit is not None and usage is not None and limit < 2**60:
            return max(limit - usage, 0)
    return None


def _rlimit_room() -> int | None:
    """Room left under ``ulimit -v`` (RLIMIT_AS), if set."""
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft == resource.RLIM_INFINITY:
        return None
    try:
        with open("/proc/self/statm") as fh:
            used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        used = 0
    return max(soft - used, 0)


def available_memory() -> tuple[int | None, str]:
    """``(bytes, where the figure comes from)``; ``(None, ...)`` where unknown.

    ``ELASTOPLAST_MEMORY_LIMIT`` (e.g. ``4G``) wins; otherwise the smallest of
    ``MemAvailable`` (``/proc/meminfo``), the room under a cgroup limit and under
    ``ulimit -v``.
    """
    env = os.environ.get(MEMORY_ENV)
    if env is not None and env.strip():
        return parse_bytes(env), f"{MEMORY_ENV}={env.strip()}"
    found = [(v, name) for v, name in ((_meminfo_available(), "MemAvailable in /proc/meminfo"),
                                       (_cgroup_room(), "the cgroup memory limit"),
                                       (_rlimit_room(), "ulimit -v")) if v is not None]
    if not found:
        return None, "unknown"
    return min(found)


def discretization_bytes(dim: int, n_nodes: int, n_elements: int, n_facets: int = 0) -> int:
    """Estimated peak memory (bytes) of building a mesh and its :class:`Discretization`.

    Since B is written directly as CSR with 32-bit indices, in chunks of elements
    (:func:`~elastoplast.fem.discretize.free_strain_operator`), no array of the build
    grows faster than the element count, and the peak is a constant per element
    (:data:`_BUILD_BYTES_PER_ELEMENT`) plus the points and facet groups (8d bytes
    each). The constants are the largest measured: tracemalloc's peak of
    ``problem_from_dict`` + ``discretize`` on the shipped graded rectangles and boxes
    was 754, 751 and 575 bytes per triangle (3,600, 57,600 and 230,400 triangles)
    and 1,528, 1,612 and 1,223 bytes per tetrahedron (5,184, 41,472 and 192,000),
    falling as the fixed-size chunks weigh less; ``tests/test_inputs.py`` checks the
    estimate against tracemalloc's peak on every run. The solvers need several times
    more than this; it is a floor, not a budget.
    """
    d = int(dim)
    return int(_BUILD_BYTES_PER_ELEMENT[d] * int(n_elements) + 8 * d * (int(n_nodes) + int(n_facets)))


def mesh_read_bytes(path: Path, size: int) -> int:
    """Estimated peak memory of ``meshio.read`` on a file of ``size`` bytes.

    Peak RSS increase / file size, measured with meshio 5.3.5 (``benchmarks/memory``,
    160k triangles and 192k tetrahedra with facet groups): gmsh 2.2 ASCII 4.9 (2D) and
    7.0 (3D), binary 3.8 and 3.8; VTU base64 + zlib 13.5 and 12.8, VTU ASCII 10.3 and
    13.4; VTK binary 1.9 and 2.1, ASCII 2.2 and 2.7. The factors (``MESH_READ_FACTORS``:
    8 for ``.msh``, 4 for ``.vtk``, 16 for ``.vtu`` and any other suffix) are these
    maxima with a margin. A compressed file can inflate far more (a zlib bomb): that
    is not bounded here.
    """
    return MESH_READ_FACTORS.get(path.suffix.lower(), MESH_READ_DEFAULT_FACTOR) * int(size)


def check_memory(need: int, field: str, what: str, advice: str) -> None:
    """Refuse when ``need`` bytes exceed the memory available now."""
    limit, source = available_memory()
    if limit is not None and need > limit:
        raise InputError(field, f"{what} needs about {format_bytes(need)}, more than the {format_bytes(limit)} "
                                f"available ({source}); {advice}")


def element_name(dim: int) -> str:
    return {2: "triangles", 3: "tetrahedra"}[dim]


def check_mesh_size(dim: int, n_nodes: int, n_elements: int, n_facets: int, field: str, what: str,
                    advice: str) -> None:
    """Refuse a mesh whose discretisation cannot fit in memory, before it is built."""
    if n_elements > MAX_ELEMENTS:
        raise InputError(field, f"{what} would have {n_elements:.3g} {element_name(dim)}: far beyond any memory; "
                                f"{advice}")
    check_memory(discretization_bytes(dim, n_nodes, n_elements, n_facets), field,
                 f"{what} ({n_elements:,} {element_name(dim)}, {n_nodes:,} nodes; mesh and operators)", advice)


def structured_counts(divisions: Sequence[int], pattern: str = "diagonal") -> tuple[int, int, int]:
    """``(n_nodes, n_elements, n_boundary_facets)`` of :func:`structured_mesh`, in exact
    integers (nothing is allocated, so absurd divisions cost nothing)."""
    div = [int(v) for v in divisions]
    dim = len(div)
    n_nodes = math.prod(v + 1 for v in div)
    if dim == 2:
        nx, ny = div
        crossed = pattern == "crossed"
        return n_nodes + (nx * ny if crossed else 0), (4 if crossed else 2) * nx * ny, 2 * (nx + ny)
    nx, ny, nz = div
    return n_nodes, 6 * nx * ny * nz, 4 * (nx * ny + ny * nz + nx * nz)
