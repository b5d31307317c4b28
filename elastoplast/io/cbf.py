"""The Conic Benchmark Format (CBF, version 3) for scalar conic programs: a writer and a reader.

CBF is the text format of the CBLIB library, read and written by MOSEK and other
conic solvers. A file holds keyword blocks (a keyword on its own line, then its
data, blocks separated by blank lines, ``#`` starting a comment). The subset
used here is the scalar part of the format:

* ``VER`` the format version (3 is written);
* ``OBJSENSE`` ``MIN`` or ``MAX``;
* ``VAR n k``, then ``k`` lines ``DOMAIN dim``: the ``n`` scalar variables ``x``,
  consecutive groups of them in one domain each;
* ``CON m k``, then ``k`` lines ``DOMAIN dim``: the ``m`` affine rows
  ``g = A x + b``, grouped the same way;
* ``OBJACOORD`` (``nnz``, then ``j value`` lines) and ``OBJBCOORD`` (one value):
  the objective ``c . x + c0``;
* ``ACOORD`` (``nnz``, then ``i j value``) and ``BCOORD`` (``nnz``, then ``i value``):
  the sparse ``A`` and ``b``. Indices are 0-based.

Domains: ``F`` free, ``L+`` nonnegative, ``L-`` nonpositive, ``L=`` zero, ``Q`` the
quadratic cone ``z_0 >= |z_1..|``, ``QR`` the rotated quadratic cone
``2 z_0 z_1 >= |z_2..|^2, z_0, z_1 >= 0``. With the CBF/MOSEK dual convention
(``y`` in the dual cone of the rows, ``c - A^T y`` in the dual cone of the
variables) these are Clarabel's and SCS's ``A_clarabel = -A``, ``b_clarabel = b``.

Floats are written by ``repr`` (shortest text that reads back to the same double),
so a file read back gives bit-identical data. Comments are ASCII lines: text put into
one goes through :func:`escape_comment` (a line break, another control character or a
non-ASCII character written as ``\\n``, ``\\uXXXX``), and :func:`cbf_text` refuses a comment
that would break the file. :func:`read_cbf` parses text only: it shares nothing with
the writer but the format.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from elastoplast.errors import InputError
from elastoplast.limits import as_path, read_bytes

#: the version this module writes
CBF_VERSION = 3
#: the scalar domains both sides understand
DOMAINS = ("F", "L+", "L-", "L=", "Q", "QR")
#: keywords of the format that this reader refuses (matrix variables, power and exponential
#: cone parameters, integer variables): a file using them is not a program of this package
UNSUPPORTED = ("PSDVAR", "PSDCON", "OBJFCOORD", "FCOORD", "HCOORD", "DCOORD", "POWCONES", "POW*CONES", "INT",
               "CHANGE")
#: the largest CBF file :func:`read_cbf` reads (its text and its parsed lists are held in memory)
MAX_CBF_BYTES = 4 * 2**30
_ESCAPES = {"\n": "\\n", "\r": "\\r", "\t": "\\t", "\\": "\\\\"}


def escape_comment(text: str) -> str:
    """``text`` as one printable ASCII line: ``\\`` doubled, line breaks and tabs as
    ``\\n``, ``\\r``, ``\\t``, any other control or non-ASCII character as ``\\uXXXX``
    (``\\UXXXXXXXX`` beyond the basic plane)."""
    out = []
    for ch in str(text):
        code = ord(ch)
        if ch in _ESCAPES:
            out.append(_ESCAPES[ch])
        elif 0x20 <= code < 0x7F:
            out.append(ch)
        else:
            out.append(f"\\u{code:04x}" if code <= 0xFFFF else f"\\U{code:08x}")
    return "".join(out)


def _check_comment(line: str) -> None:
    """Refuse comment text that is not one printable ASCII line (it would break the file)."""
    if not isinstance(line, str):
        raise TypeError(f"a CBF comment is text, got {type(line).__name__}")
    bad = [ch for ch in line if not 0x20 <= ord(ch) < 0x7F]
    if bad:
        what = "a line break" if any(ch in "\n\r\v\f\x1c\x1d\x1e\x85\u2028\u2029" for ch in bad) else \
            "a control or non-ASCII character"
        raise ValueError(f"a CBF comment holds {what} ({bad[0]!r}): pass it through escape_comment")


@dataclass
class CBFProgram:
    """``min (or max) c . x + c0`` subject to ``x`` in ``var_cones`` and ``A x + b`` in
    ``con_cones``. Cones are ``(domain, dim)`` pairs in order; ``A`` is ``(m, n)``."""

    c: np.ndarray
    A: sp.csr_matrix
    b: np.ndarray
    var_cones: list[tuple[str, int]]
    con_cones: list[tuple[str, int]]
    c0: float = 0.0
    sense: str = "MIN"
    version: int = CBF_VERSION
    comments: list[str] = field(default_factory=list)

    @property
    def n(self) -> int:
        return int(self.c.size)

    @property
    def m(self) -> int:
        return int(self.b.size)


def _floats(values) -> list[str]:
    return [repr(v) for v in np.asarray(values, dtype=float).tolist()]


def _check(prog: CBFProgram) -> None:
    for what, cones, size in (("VAR", prog.var_cones, prog.n), ("CON", prog.con_cones, prog.m)):
        bad = [d for d, _ in cones if d not in DOMAINS]
        if bad:
            raise ValueError(f"{what}: unknown domain(s) {sorted(set(bad))}")
        if sum(int(k) for _, k in cones) != size:
            raise ValueError(f"{what}: the cones cover {sum(int(k) for _, k in cones)} of {size} entries")
    if prog.A.shape != (prog.m, prog.n):
        raise ValueError(f"A is {prog.A.shape}, expected {(prog.m, prog.n)}")
    if not all(np.all(np.isfinite(a)) for a in (prog.c, prog.b, prog.A.data)) or not np.isfinite(prog.c0):
        raise ValueError("the program holds non-finite numbers")


def cbf_text(prog: CBFProgram) -> str:
    """The CBF file of ``prog`` as one string."""
    _check(prog)
    for line in prog.comments:
        _check_comment(line)
    out = [f"# {line}" for line in prog.comments]
    out += ["VER", str(prog.version), "", "OBJSENSE", prog.sense, ""]
    for key, cones, size in (("VAR", prog.var_cones, prog.n), ("CON", prog.con_cones, prog.m)):
        if size:
            out += [key, f"{size} {len(cones)}"] + [f"{d} {int(k)}" for d, k in cones] + [""]
    j = np.flatnonzero(prog.c)
    if j.size:
        out += ["OBJACOORD", str(j.size)] + [f"{a} {v}" for a, v in zip(j.tolist(), _floats(prog.c[j]))] + [""]
    if prog.c0 != 0.0:
        out += ["OBJBCOORD", repr(float(prog.c0)), ""]
    A = sp.coo_matrix(prog.A)
    keep = A.data != 0.0
    rows, cols, vals = A.row[keep], A.col[keep], A.data[keep]
    order = np.lexsort((cols, rows))
    if order.size:
        out += ["ACOORD", str(order.size)]
        out += [f"{i} {jj} {v}" for i, jj, v in zip(rows[order].tolist(), cols[order].tolist(), _floats(vals[order]))]
        out.append("")
    i = np.flatnonzero(prog.b)
    if i.size:
        out += ["BCOORD", str(i.size)] + [f"{a} {v}" for a, v in zip(i.tolist(), _floats(prog.b[i]))] + [""]
    return "\n".join(out).rstrip("\n") + "\n"  # one final newline


# ----------------------------------------------------------------------------
# the reader: text in, arrays out
# ----------------------------------------------------------------------------


def _lines(text: str) -> list[str]:
    """The file's lines without comments and blank lines (blank lines only separate blocks)."""
    out = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if line:
            out.append(line)
    return out


def read_cbf(path: str | Path) -> CBFProgram:
    """Parse a CBF file with scalar variables and constraints (see the module docstring).

    Refuses (``InputError`` naming ``cbf``) what it does not read: no path, a missing,
    empty or unreadable file, a folder or device, a file above :data:`MAX_CBF_BYTES`,
    text that is not ASCII, matrix variables, integer variables, power and exponential
    cones' parameters, unknown keywords, indices out of range and counts that do not
    add up.
    """
    path = as_path(path, "cbf", "CBF file")
    raw = read_bytes(path, "cbf", "CBF file", MAX_CBF_BYTES)
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        raise InputError("cbf", f"{path} is not a CBF file: byte 0x{raw[exc.start]:02x} at offset {exc.start} is not "
                                "ASCII text") from None
    del raw
    lines = _lines(text)
    pos = 0

    def fail(message: str):
        raise InputError("cbf", f"{path}: {message}")

    def take(count: int, key: str) -> list[list[str]]:
        nonlocal pos
        if pos + count > len(lines):
            fail(f"{key}: expected {count} more line(s), the file ends")
        chunk = [ln.split() for ln in lines[pos:pos + count]]
        pos += count
        return chunk

    version, sense, c0 = None, "MIN", 0.0
    var_cones: list[tuple[str, int]] = []
    con_cones: list[tuple[str, int]] = []
    n = m = None
    c_idx, c_val, a_i, a_j, a_v, b_i, b_v = [], [], [], [], [], [], []
    try:
        while pos < len(lines):
            key = lines[pos].split()[0]
            pos += 1
            if key == "VER":
                version = int(take(1, key)[0][0])
                if not 1 <= version <= 4:
                    fail(f"VER {version}: versions 1 to 4 are read")
            elif key == "OBJSENSE":
                sense = take(1, key)[0][0]
                if sense not in ("MIN", "MAX"):
                    fail(f"OBJSENSE {sense}: MIN or MAX")
            elif key in ("VAR", "CON"):
                total, count = (int(t) for t in take(1, key)[0][:2])
                cones = [(d, int(k)) for d, k in (row[:2] for row in take(count, key))]
                if any(d not in DOMAINS for d, _ in cones):
                    fail(f"{key}: domains other than {', '.join(DOMAINS)}")
                if sum(k for _, k in cones) != total:
                    fail(f"{key}: the cone sizes add up to {sum(k for _, k in cones)}, not {total}")
                if key == "VAR":
                    n, var_cones = total, cones
                else:
                    m, con_cones = total, cones
            elif key == "OBJACOORD":
                for j, v in take(int(take(1, key)[0][0]), key):
                    c_idx.append(int(j))
                    c_val.append(float(v))
            elif key == "OBJBCOORD":
                c0 = float(take(1, key)[0][0])
            elif key == "ACOORD":
                for i, j, v in take(int(take(1, key)[0][0]), key):
                    a_i.append(int(i))
                    a_j.append(int(j))
                    a_v.append(float(v))
            elif key == "BCOORD":
                for i, v in take(int(take(1, key)[0][0]), key):
                    b_i.append(int(i))
                    b_v.append(float(v))
            elif key in UNSUPPORTED or key.endswith("CONES"):
                fail(f"keyword {key} is not read (scalar conic programs only)")
            else:
                fail(f"unknown keyword {key!r}")
    except ValueError as exc:  # a malformed number or a short line
        if isinstance(exc, InputError):
            raise
        fail(f"malformed data near line {pos}: {exc}")
    if version is None:
        fail("no VER block")
    n, m = n or 0, m or 0
    for name, idx, size in (("OBJACOORD", c_idx, n), ("ACOORD row", a_i, m), ("ACOORD column", a_j, n),
                            ("BCOORD", b_i, m)):
        if idx and not (0 <= min(idx) and max(idx) < size):
            fail(f"{name} index out of range 0..{size - 1}")
    c = np.zeros(n)
    np.add.at(c, np.asarray(c_idx, dtype=int), c_val)
    b = np.zeros(m)
    np.add.at(b, np.asarray(b_i, dtype=int), b_v)
    A = sp.csr_matrix((np.asarray(a_v, dtype=float), (np.asarray(a_i, dtype=int), np.asarray(a_j, dtype=int))),
                      shape=(m, n))
    return CBFProgram(c=c, A=A, b=b, var_cones=var_cones, con_cones=con_cones, c0=c0, sense=sense, version=version)
