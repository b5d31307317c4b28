"""The discrete problem (2.1) exported for any conic solver (docs/math.md, section 7).

:func:`export` writes the stress form (S) (or the displacement form (D)) as a pure
conic program: a linear objective, linear equalities and inequalities, one
second-order cone per element and the quadratic energy moved into a rotated
quadratic cone, so that a solver without a quadratic objective takes it. Two
formats:

* ``cbf``: the Conic Benchmark Format, version 3 (:mod:`elastoplast.io.cbf`), read by
  MOSEK and the CBLIB tools; rows ``g = A x + b``, domains ``L=``, ``L+``, ``Q``, ``QR``;
* ``npz``: Clarabel's and SCS's canonical form, minimise ``1/2 x'Px + q'x`` subject to
  ``A x + s = b`` with ``s`` in (zero, nonnegative, second-order cones), in that
  order; sparse matrices as CSC arrays (``A_data``, ``A_indices``, ``A_indptr``,
  ``A_shape``, the same for ``P``, its upper triangle); rotated cones converted to
  second-order cones by ``(a, b, v) -> ((a+b)/sqrt2, (a-b)/sqrt2, v)``.

Each file gets a JSON sidecar ``FILE.json``: the index ranges of the variables (the
element stresses ``tau`` in Mandel order element by element, ``xi``, the contact
forces ``lam`` in the order of ``Discretization.contact_nodes``), the rows whose
duals are the displacements (the free dofs, ``dof = node * dim + component``, listed
in ``free_dofs``) and ``U``, the units, the scaling, the mesh's sizes and the
problem's content hash. :func:`answer_from_solution` maps a solver's primal and dual
vectors back to ``(sigma, xi, u, U, lambda)`` in the problem's units, for
:func:`~elastoplast.certificate.kkt.certify` to judge.

**The objective is in the problem's own units**: at the optimum of (S) its value is
``1/2 sum_T |T| (tau_T A tau_T + xi_T^2 / H) + sum_i psi_i lam_i = -Pi_h``
(``Solution.value_S``); for (D) it is ``Pi_h`` (``Solution.value_D``).

**Scaling.** The unknowns are not the problem's: ``x = D x_tilde`` with a diagonal
``D`` and the rows scaled by positive factors, the objective ``c . x`` left unchanged.
With the working units of :func:`~elastoplast.fem.discretize.nondimensionalize`
(stress ``S`` = mean contact pressure, length ``L`` = mean element size,
displacement ``L S / E``, force ``S L^(d-1)``, energy = force x displacement) and the
element weights ``w_T = sqrt(|T| / mean |T|)``:

* (S): ``tau_T = S tau~_T / w_T``, ``xi_T = S xi~_T / w_T``, ``lam = force lam~``;
  equilibrium and force-balance rows divided by the force unit; the yield cone of
  element ``T`` reads ``(w_T sigma_y / S + xi~_T, sqrt(3/2) Q^T tau~_T)``;
* (D): ``u = displacement v~``, ``U = displacement V~``, ``p_T = (S/E) Q p~_T / w_T``,
  ``kappa_T = (S/E) kappa~_T / w_T``; contact rows divided by the displacement unit;
* the energy (a sum of element energies of very different sizes) is one rotated cone
  ``2 t c >= |v|^2`` over every element's ``v_T`` (``v_T = L_A^T tau~_T`` and
  ``xi~_T / sqrt(H/E)``, ``A = L_A L_A^T`` in units of 1/E), whose epigraph variable
  ``t`` enters the objective with the coefficient ``c`` (times the energy unit). One cone, not one per element:
  an element energy of 1e-10 in a cone of its own, next to a constant of 1, is
  resolved only to the solver's absolute tolerance (and to 1e-6 of itself after the
  rotated-to-second-order conversion, which cancels ``(t+1) - (t-1)``). The constant
  ``c = sqrt(e)`` for an a-priori estimate ``e = 1/2 F~ max(l~, 1)`` of the energy in
  working units (``F~`` the force, ``l~`` the contact zone's size in working lengths)
  balances ``t`` against ``c``: the conversion then loses ``|log10(t/c)| = |log10(e_true/e)|``
  digits, none at balance (measured: the estimate within a factor 2 to 6 of the true
  energy on four test meshes; Clarabel's certificate unchanged for estimates off by
  1e-2..1e2, degraded for 1e-4 or 1e4).

Every variable is then O(1) where the stresses are of the order of the contact
pressure, whatever the units and the element sizes, so a solver at its default
tolerance resolves the optimum to about that tolerance relative to the energy.
The obstacle is capped at ``PSI_CAP`` displacement units as in the package's own
solvers (``psi_capped`` in the sidecar counts such nodes; they carry no force unless
the displacements reach 1e9 displacement units, so the optimum is unchanged). A solver's absolute tolerances
apply to the objective in the problem's units: the sidecar's ``units.energy`` says
how large one working energy unit is.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from elastoplast.certificate.solution import Solution, Status, make_solution
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import PSI_CAP, Discretization, check_hencky, nondimensionalize
from elastoplast.fem.locking import BEARING_FACTOR, SMALL_STRAIN_LIMIT
from elastoplast.io.cbf import CBFProgram, cbf_text, escape_comment
from elastoplast.io.export_files import (  # noqa: F401  (read_sidecar, load_npz: part of this module's API)
    SIDECAR_SUFFIX,
    check_export_path,
    load_npz,
    read_sidecar,
    sidecar_path,
    write_pair,
)
from elastoplast.io.store import resolve
from elastoplast.fem.stress_form import deviatoric_basis, element_weights, equilibrium_rows, force_row, yield_rows
from elastoplast.version import __version__
from elastoplast.fem.locking import overload

FORMATS = ("cbf", "npz")
FORMS = ("S", "D")
#: "cone": the energy in a rotated cone (pure conic, any format); "quadratic": in P (npz only)
ENERGY = ("cone", "quadratic")


@dataclass(frozen=True)
class Built:
    """A form of (2.1) in CBF's convention (``g = A x + b``), with ``P`` (the upper
    triangle, or None) for the quadratic variant, and the sidecar's description."""

    program: CBFProgram
    P: sp.csc_matrix | None
    variables: dict[str, list[int]]
    rows: dict[str, list[int]]
    scaling: dict[str, Any]


def _scales(disc: Discretization) -> tuple[Discretization, dict[str, float]]:
    nd, units = nondimensionalize(disc)
    d = disc.measure_dim
    size = float(nd.contact_area.sum()) ** (1.0 / (d - 1))
    estimate = 0.5 * nd.force * max(size, 1.0)
    s = {"stress": float(units.stress), "length": float(units.length), "displacement": float(units.displacement),
         "force": float(units.force), "energy": float(units.force * units.displacement), "E": float(units.E),
         "energy_estimate": float(estimate), "energy_cone_constant": float(np.sqrt(estimate))}
    return nd, s


class _Rows:
    """COO triplets of ``A`` and ``b`` collected block by block, with their cones."""

    def __init__(self, n_cols: int):
        self.n, self.m = n_cols, 0
        self.r, self.c, self.v, self.b = [], [], [], []
        self.cones: list[tuple[str, int]] = []
        self.blocks: dict[str, list[int]] = {}

    def add(self, name: str, size: int, rows, cols, vals, b_rows=(), b_vals=(), cones=()):
        self.r.append(self.m + np.asarray(rows, dtype=np.int64))
        self.c.append(np.asarray(cols, dtype=np.int64))
        self.v.append(np.asarray(vals, dtype=float))
        b = np.zeros(size)
        b[np.asarray(b_rows, dtype=np.int64)] = b_vals
        self.b.append(b)
        self.cones += list(cones)
        self.blocks[name] = [self.m, self.m + size]
        self.m += size

    def matrix(self):
        A = sp.csr_matrix((np.concatenate(self.v), (np.concatenate(self.r), np.concatenate(self.c))),
                          shape=(self.m, self.n))
        A.eliminate_zeros()
        return A, np.concatenate(self.b)


def _kron_blocks(M: np.ndarray, n: int) -> sp.coo_matrix:
    """``I_n (x) M``: one copy of the small block ``M`` per element."""
    return sp.kron(sp.eye(n), sp.csr_matrix(M)).tocoo()


def _energy_rows(rows: _Rows, t_col: int, c_e: float, blocks: list[sp.coo_matrix]):
    """The rotated cone ``(t, c_e, G_1 x, G_2 x, ...)``: ``2 t c_e >= |G x|^2``."""
    r, c, v, off = [np.array([0])], [np.array([t_col])], [np.array([1.0])], 2
    for G in blocks:
        r.append(off + G.row)
        c.append(G.col)
        v.append(G.data)
        off += G.shape[0]
    rows.add("energy", off, np.concatenate(r), np.concatenate(c), np.concatenate(v), [1], [c_e], [("QR", off)])


def _gram_upper(blocks: list[sp.coo_matrix], n_cols: int, factor: float) -> sp.csc_matrix:
    G = sp.vstack([sp.csr_matrix(B) for B in blocks], format="csr")
    G = sp.csr_matrix((G.data, G.indices, G.indptr), shape=(G.shape[0], n_cols))
    return sp.triu(factor * (G.T @ G), format="csc")


def _column_block(M: sp.coo_matrix, col0: int, n_cols: int) -> sp.coo_matrix:
    return sp.coo_matrix((M.data, (M.row, M.col + col0)), shape=(M.shape[0], n_cols))


def energy_term(rows, blocks, energy: str, t0: int, n_cols: int, s: dict):
    """The energy of a form: rows of the rotated cone on the energy variable ``t0`` (``energy =
    "cone"``; returns None), or the upper triangle of ``P`` (``"quadratic"``)."""
    if energy == "cone":
        _energy_rows(rows, t0, s["energy_cone_constant"], blocks)
        return None
    return _gram_upper(blocks, n_cols, s["energy"])


def stress_form(disc: Discretization, energy: str = "cone") -> Built:
    """(S) in the exported variables (module docstring): ``tau~`` (``n k``), ``xi~``
    (``n``, absent when H = 0), ``lam~`` (``n_contact``, domain ``L+``) and, with
    ``energy="cone"``, the epigraph ``t``; rows: equilibrium and force balance (``L=``),
    one ``Q`` of size k per element, the energy ``QR``."""
    check_hencky(disc, "the export of (S)")
    nd, s = _scales(disc)
    n, k, nc, nf = nd.n_elements, nd.k, nd.n_contact, nd.n_free
    m = nd.material
    has_xi = m.hardening > 0
    w = element_weights(nd)
    tau0, xi0 = 0, n * k
    lam0 = xi0 + (n if has_xi else 0)
    t0 = lam0 + nc
    n_cols = t0 + (1 if energy == "cone" else 0)

    c = np.zeros(n_cols)
    c[lam0:t0] = s["energy"] * nd.psi
    if energy == "cone":
        c[t0] = s["energy"] * s["energy_cone_constant"]
    rows = _Rows(n_cols)
    for name, g, cones in (("equilibrium", equilibrium_rows(nd, tau0, lam0), [("L=", nf + 1)]),  # with the force row
                           ("force", force_row(nd, lam0), []),
                           ("yield", yield_rows(k, w, m.yield_stress, tau0, xi0 if has_xi else None), [("Q", k)] * n)):
        rows.add(name, g.n_rows, g.row, g.col, g.val, g.h_rows, g.h_vals, cones)  # CBF's A x + b is G x + h

    LA = np.linalg.cholesky(m.compliance(nd.dim))  # A = LA LA^T, tau A tau = |LA^T tau|^2
    blocks = [_column_block(_kron_blocks(LA.T, n), tau0, n_cols)]
    if has_xi:
        blocks.append(_column_block(sp.diags(np.full(n, 1.0 / np.sqrt(m.hardening))).tocoo(), xi0, n_cols))
    P = energy_term(rows, blocks, energy, t0, n_cols, s)
    A, b = rows.matrix()
    var_cones = [("F", lam0), ("L+", nc)] + ([("F", 1)] if energy == "cone" else [])
    prog = CBFProgram(c=c, A=A, b=b, var_cones=[vc for vc in var_cones if vc[1] > 0], con_cones=rows.cones)
    variables = {"tau": [tau0, xi0], "xi": [xi0, lam0] if has_xi else None, "lam": [lam0, t0],
                 "t": [t0, t0 + 1] if energy == "cone" else None}
    s.update(psi_capped=int(np.count_nonzero(nd.psi >= PSI_CAP)), yield_stress=float(m.yield_stress),
             hardening=float(m.hardening))
    return Built(prog, P, variables, rows.blocks, s)


def displacement_form(disc: Discretization, energy: str = "cone") -> Built:
    """(D) in the exported variables: ``v~`` (free dofs), ``V~``, ``p~`` (``n (k-1)``,
    trace-free basis), ``kappa~`` (``n``) and, with ``energy="cone"``, ``t``; rows: the
    contact inequalities (``L+``), one flow cone ``Q`` of size k per element, the
    elastic and hardening energy ``QR``."""
    check_hencky(disc, "the export of (D)")
    nd, s = _scales(disc)
    n, k, nc, nf = nd.n_elements, nd.k, nd.n_contact, nd.n_free
    m = nd.material
    w = element_weights(nd)
    v0, V0, p0 = 0, nf, nf + 1
    kap0 = p0 + n * (k - 1)
    t0 = kap0 + n
    n_cols = t0 + (1 if energy == "cone" else 0)

    c = np.zeros(n_cols)
    c[V0] = -s["energy"] * nd.force
    c[kap0:t0] = s["energy"] * w * m.yield_stress
    if energy == "cone":
        c[t0] = s["energy"] * s["energy_cone_constant"]
    rows = _Rows(n_cols)
    N = nd.N.tocoo()
    rows.add("contact", nc, np.concatenate([N.row, np.arange(nc)]), np.concatenate([v0 + N.col, np.full(nc, V0)]),
             np.concatenate([N.data, -np.ones(nc)]), np.arange(nc), nd.psi, [("L+", nc)])
    pk = _kron_blocks(np.sqrt(2.0 / 3.0) * np.eye(k - 1), n)
    rows.add("flow", n * k, np.concatenate([np.arange(n) * k, (pk.row // (k - 1)) * k + 1 + pk.row % (k - 1)]),
             np.concatenate([kap0 + np.arange(n), p0 + pk.col]), np.concatenate([np.ones(n), pk.data]),
             cones=[("Q", k)] * n)

    LC = np.linalg.cholesky(m.stiffness(nd.dim))
    WB = (_kron_blocks(LC.T, n) @ sp.diags(np.repeat(w, k)) @ nd.B).tocoo()
    LQ = _kron_blocks(-LC.T @ deviatoric_basis(k), n)
    elastic = (_column_block(WB, v0, n_cols) + _column_block(LQ, p0, n_cols)).tocoo()
    blocks = [elastic]
    if m.hardening > 0:
        blocks.append(_column_block(sp.diags(np.full(n, np.sqrt(m.hardening))).tocoo(), kap0, n_cols))
    P = energy_term(rows, blocks, energy, t0, n_cols, s)
    A, b = rows.matrix()
    prog = CBFProgram(c=c, A=A, b=b, var_cones=[("F", n_cols)], con_cones=rows.cones)
    variables = {"v": [v0, V0], "V": [V0, p0], "p": [p0, kap0], "kappa": [kap0, t0],
                 "t": [t0, t0 + 1] if energy == "cone" else None}
    s.update(psi_capped=int(np.count_nonzero(nd.psi >= PSI_CAP)), yield_stress=float(m.yield_stress),
             hardening=float(m.hardening))
    return Built(prog, P, variables, rows.blocks, s)


# ----------------------------------------------------------------------------
# CBF's convention -> Clarabel's and SCS's
# ----------------------------------------------------------------------------


def clarabel_form(prog: CBFProgram, P: sp.spmatrix | None = None) -> dict[str, Any]:
    """``prog`` as ``(P, q, A, b)`` with ``A x + s = b``, ``s`` in zero, nonnegative and
    second-order cones in that order. ``row_of[i]`` is the row of CBF row ``i`` (-1 for
    rows in ``F``), ``var_row[j]`` the row holding variable ``j``'s own domain (-1 for
    ``F``). Duals: ``z = y`` on ``L=``, ``L+`` and ``Q`` rows; on a ``QR`` cone
    ``z = T y`` with the symmetric orthogonal ``T`` of the conversion."""
    A = sp.csr_matrix(prog.A)
    n = prog.n
    r2 = 1.0 / np.sqrt(2.0)
    parts = {"zero": [], "nonnegative": [], "soc": []}  # (cbf rows or -(var+1), matrix, rhs, soc size)

    def walk(cones, is_var):
        start = 0
        for dom, size in cones:
            idx = np.arange(start, start + size)
            start += size
            if dom == "F":
                continue
            if is_var:
                M, rhs = -sp.csr_matrix((np.ones(size), (np.arange(size), idx)), shape=(size, n)), np.zeros(size)
            else:
                M, rhs = -A[idx], prog.b[idx].copy()
            key = {"L=": "zero", "L+": "nonnegative", "L-": "nonnegative"}.get(dom, "soc")
            if dom == "L-":
                M, rhs = -M, -rhs
            if dom == "QR":
                T = sp.identity(size, format="lil")
                T[0, 0] = T[0, 1] = T[1, 0] = r2
                T[1, 1] = -r2
                T = sp.csr_matrix(T)
                M, rhs = T @ M, T @ rhs
            tag = -(idx + 1) if is_var else idx
            parts[key].append((tag, sp.csr_matrix(M), np.asarray(rhs).ravel(), size if key == "soc" else 0))

    walk(prog.con_cones, False)
    walk(prog.var_cones, True)
    order = parts["zero"] + parts["nonnegative"] + parts["soc"]
    row_of, var_row, at = np.full(prog.m, -1), np.full(n, -1), 0
    for tag, M, _, _ in order:
        here = at + np.arange(M.shape[0])
        row_of[tag[tag >= 0]] = here[tag >= 0]
        var_row[-tag[tag < 0] - 1] = here[tag < 0]
        at += M.shape[0]
    A_out = sp.vstack([M for _, M, _, _ in order], format="csc") if order else sp.csc_matrix((0, n))
    b_out = np.concatenate([r for _, _, r, _ in order]) if order else np.zeros(0)
    sign = -1.0 if prog.sense == "MAX" else 1.0
    P = sp.csc_matrix((n, n)) if P is None else sp.csc_matrix(P)
    return {"P": P, "q": sign * prog.c, "A": A_out, "b": b_out,
            "zero": sum(M.shape[0] for _, M, _, _ in parts["zero"]),
            "nonnegative": sum(M.shape[0] for _, M, _, _ in parts["nonnegative"]),
            "second_order": [sz for _, _, _, sz in parts["soc"]], "row_of": row_of, "var_row": var_row}


# ----------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ExportInfo:
    """What :func:`export` wrote."""

    path: Path
    sidecar: Path
    format: str
    form: str
    n_variables: int
    n_rows: int
    cones: str
    objective: str

    def line(self) -> str:
        """The one-line summary for the command line."""
        return (f"exported ({self.form}) to {_one_line(self.path)} [{self.format}]: {self.n_variables} variables, "
                f"{self.n_rows} rows, cones {self.cones}; optimal value = {self.objective}; map back with "
                f"{_one_line(self.sidecar)}")


def _one_line(path: Path) -> str:
    """A path for one line of output: control characters (a newline in a file name) escaped."""
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in str(path))


def _cone_summary(cones: list[tuple[str, int]]) -> str:
    out: list[list] = []
    for dom, size in cones:
        if out and out[-1][0] == dom and out[-1][1] == size:
            out[-1][2] += 1
        else:
            out.append([dom, size, 1])
    return ", ".join(f"{cnt} x {d}({sz})" if cnt > 1 else f"{d}({sz})" for d, sz, cnt in out)


def check_export_options(format: str, form: str, energy: str) -> None:
    """Refuse an unknown format, form or energy, and a quadratic energy in CBF."""
    for name, value, allowed in (("format", format, FORMATS), ("form", form, FORMS), ("energy", energy, ENERGY)):
        if not isinstance(value, str) or value not in allowed:
            raise InputError(name, f"expected one of {', '.join(allowed)}, got {value!r}")
    if format == "cbf" and energy != "cone":
        raise InputError("energy", "CBF has no quadratic objective: use energy='cone' or format='npz'")


def limit_load_note(disc: Discretization) -> str | None:
    """A one-line note when the force is plainly above what the body can carry, else None.

    The cheap test of :func:`~elastoplast.fem.locking.check_hardening_carries_load`: a
    body that flows carries a mean contact pressure of at most ``BEARING_FACTOR`` flow
    stresses, so with ``F / |Gamma_0|`` above ``BEARING_FACTOR sigma_y`` and ``H = 0`` the
    force is above the limit load (the program (S) is infeasible, (D) unbounded), and
    with ``H > 0`` above ``BEARING_FACTOR (sigma_y + H SMALL_STRAIN_LIMIT)`` its answer
    leaves small strains. Forces between the limit load and this estimate pass unnoticed
    (``elastoplast limit`` brackets the limit load)."""
    excess = overload(disc)
    if excess is None:
        return None
    pressure, _ = excess
    if disc.material.hardening <= 0:
        return (f"the force {disc.force:g} is above the limit load (mean pressure over the contact zone {pressure:.3g} "
                f"> {BEARING_FACTOR:g} sigma_y): the exported program has no solution")
    return (f"the force {disc.force:g} is far above the limit load (mean pressure over the contact zone "
            f"{pressure:.3g} > {BEARING_FACTOR:g} (sigma_y + {SMALL_STRAIN_LIMIT:g} H)): the optimum leaves small "
            "strains")


def export(disc: Discretization, path: str | Path, format: str = "cbf", form: str = "S", *,
           energy: str = "cone", protect=()) -> ExportInfo:
    """Write (S) (``form="S"``) or (D) of ``disc`` to ``path`` as ``format`` ("cbf" or
    "npz") and its sidecar to ``path + ".json"``. ``energy="quadratic"`` (npz only) keeps
    the energy in ``P`` instead of a rotated cone. Returns an :class:`ExportInfo`.

    ``path`` is checked before any work (:func:`~elastoplast.io.export_files.check_export_path`,
    ``InputError`` naming ``path``): an existing file is replaced only when it is an
    earlier export (its sidecar names it with its SHA-256); ``protect`` lists files never
    written over (the problem file, its mesh file). Both files appear together or not
    at all (:func:`~elastoplast.io.export_files.write_pair`)."""
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    check_export_options(format, form, energy)
    path = check_export_path(path, format, "path", protect)
    built = (stress_form if form == "S" else displacement_form)(disc, energy)
    prog = built.program
    title = "stress" if form == "S" else "displacement"
    prog.comments = [f"elastoplast {__version__}: the {title} form ({form}) of C. Johnson's contact problem (2.1)",
                     f"variables and rows: see {escape_comment(path.name + SIDECAR_SUFFIX)}"]
    if format == "cbf":
        data = cbf_text(prog).encode("ascii")  # cbf_text refuses anything but printable ASCII comments
        rows, n_rows, cones = built.rows, prog.m, _cone_summary(prog.con_cones)
    else:
        cf = clarabel_form(prog, built.P)
        rows = {name: [int(cf["row_of"][a]), int(cf["row_of"][a]) + (b - a)] for name, (a, b) in built.rows.items()}
        if form == "S":
            a, b = built.variables["lam"]
            rows["contact_sign"] = [int(cf["var_row"][a]), int(cf["var_row"][a]) + (b - a)]
        n_rows = cf["A"].shape[0]
        cones = f"{cf['zero']} zero, {cf['nonnegative']} nonnegative, " + _cone_summary(
            [("SOC", sz) for sz in cf["second_order"]])
        arrays = {"q": cf["q"], "b": cf["b"], "zero": np.int64(cf["zero"]), "nonnegative": np.int64(cf["nonnegative"]),
                  "second_order": np.asarray(cf["second_order"], dtype=np.int64),
                  "free_dofs": disc.free.astype(np.int64), "contact_nodes": disc.contact_nodes.astype(np.int64)}
        for name in ("A", "P"):
            M = sp.csc_matrix(cf[name])
            arrays.update({f"{name}_data": M.data, f"{name}_indices": M.indices.astype(np.int64),
                           f"{name}_indptr": M.indptr.astype(np.int64), f"{name}_shape": np.asarray(M.shape, np.int64)})
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        data = buf.getvalue()
    objective = ("value(S) = -Pi_h = 1/2 [sigma_hat, sigma_hat] + psi . lam (Solution.value_S)" if form == "S"
                 else "value(D) = Pi_h, the total potential energy (Solution.value_D)")
    meta = _sidecar(disc, built, format, form, energy, rows, n_rows, hashlib.sha256(data).hexdigest(), path.name, objective)
    side = write_pair(path, data, json.dumps(meta, indent=1) + "\n", "path")
    return ExportInfo(path, side, format, form, prog.n, n_rows, cones, objective)


def _sidecar(disc, built: Built, format, form, energy, rows, n_rows, sha, name, objective) -> dict[str, Any]:
    s = built.scaling
    if form == "S":
        duals = {"u_free": "y[rows.equilibrium] * dual_to_displacement, then scattered to the nodes' dofs free_dofs",
                 "U": "y[rows.force] * dual_to_displacement",
                 "dual_to_displacement": 1.0 / s["force"],
                 "gaps": "the reduced costs of lam (npz: y[rows.contact_sign]) * dual_to_displacement"}
        scaling = {"tau": "tau_T = stress * x[tau]_T / w_T (Mandel, element by element)",
                   "xi": "xi_T = stress * x[xi]_T / w_T", "lam": "lam = force * x[lam]"}
    else:
        duals = {"contact_force": "y[rows.contact] * dual_to_force", "dual_to_force": 1.0 / s["displacement"]}
        scaling = {"v": "u_free = displacement * x[v]", "V": "U = displacement * x[V]",
                   "p": "p_T = (stress / E) Q x[p]_T / w_T, Q the trace-free basis of conic.deviatoric_basis",
                   "kappa": "kappa_T = (stress / E) x[kappa]_T / w_T",
                   "sigma": "sigma_T = C (B_T u - p_T), xi_T = H kappa_T"}
    duals["convention"] = ("CBF/MOSEK: Lagrangian c.x - y.(A x + b), y in the dual cone of each row block; "
                           "Clarabel/SCS: c + A'z = 0 with A = -A_cbf, the same y on L=, L+ and Q rows")
    scaling.update(w="w_T = sqrt(|T| / mean |T|)", t="energy = units.energy * energy_cone_constant * x[t] at the optimum",
                   rows=("equilibrium and force rows / force unit; contact rows / displacement unit; each cone in "
                         "working units; the objective c.x unchanged, in the problem's units"))
    try:
        problem_id = resolve(disc.problem, "export", {}).problem_id
    except (TypeError, ValueError, AttributeError):  # an unusual problem object: no hash, the sizes still check
        problem_id = None
    return {
        "file": name, "format": format, "cbf_version": 3 if format == "cbf" else None, "form": form,
        "energy": energy, "sha256": sha, "elastoplast_version": __version__, "problem_id": problem_id,
        "n_variables": built.program.n, "n_rows": n_rows,
        "objective": {"sense": "min", "value": objective, "offset": 0.0},
        "mesh": {"dim": disc.dim, "n_nodes": int(disc.mesh.n_nodes), "n_elements": int(disc.n_elements),
                 "k": int(disc.k), "n_free_dofs": int(disc.n_free), "n_contact_nodes": int(disc.n_contact)},
        "units": {"system": "the problem's own (those of its input: e.g. MPa, mm, N)",
                  **{key: s[key] for key in ("stress", "length", "displacement", "force", "energy", "E")}},
        "scaling": {**scaling, **{key: s[key] for key in ("energy_estimate", "energy_cone_constant", "psi_capped")},
                    "psi_cap": PSI_CAP},
        "variables": built.variables, "rows": rows, "duals": duals,
        "free_dofs": disc.free.astype(int).tolist(), "contact_nodes": disc.contact_nodes.astype(int).tolist(),
    }


# ----------------------------------------------------------------------------
# answers back
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ExportAnswer:
    """A solver's answer to an exported program, in the problem's units."""

    sigma: np.ndarray
    xi: np.ndarray
    u_free: np.ndarray
    U: float
    contact_force: np.ndarray


def _check_meta(disc: Discretization, meta: dict[str, Any]) -> None:
    needed = ("form", "variables", "rows", "units", "mesh", "duals")
    if not isinstance(meta, dict) or any(key not in meta for key in needed):
        raise InputError("meta", f"expected an export's sidecar (read_sidecar), a dict with {', '.join(needed)}")
    mesh = meta.get("mesh", {})
    mine = {"dim": disc.dim, "n_elements": disc.n_elements, "n_free_dofs": disc.n_free,
            "n_contact_nodes": disc.n_contact}
    wrong = [key for key, value in mine.items() if mesh.get(key) != value]
    if wrong:
        raise InputError("meta", f"the sidecar describes another problem ({', '.join(wrong)} differ)")
    _, s = _scales(disc)
    for key in ("stress", "length", "force", "displacement"):
        if not np.isclose(meta["units"][key], s[key], rtol=1e-12, atol=0.0):
            raise InputError("meta", f"the sidecar's {key} unit is not this problem's")


def _vector(v, name: str, ranges: dict[str, Any], size: int | None) -> np.ndarray:
    """``v`` as a 1-D float array covering every index range of ``ranges`` (of length
    ``size`` when given), or an InputError naming ``name``."""
    try:
        arr = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(name, f"expected a vector of numbers, got {type(v).__name__} ({exc})") from None
    if arr.ndim != 1:
        raise InputError(name, f"expected a vector (1-D), got an array of shape {arr.shape}")
    need = max((int(r[1]) for r in ranges.values() if isinstance(r, (list, tuple)) and len(r) == 2), default=0)
    if size is not None and arr.size != int(size):
        raise InputError(name, f"has {arr.size} entries; the exported program has {int(size)}")
    if arr.size < need:
        raise InputError(name, f"has {arr.size} entries, fewer than the {need} the sidecar's ranges need")
    return arr


def answer_from_solution(disc: Discretization, x, y, meta: dict[str, Any]) -> ExportAnswer:
    """Map a solver's primal ``x`` and dual ``y`` of the exported program described by
    ``meta`` (:func:`read_sidecar`) back to ``(sigma, xi, u_free, U, contact_force)`` in
    the problem's units. ``y``: the duals of the file's rows with the convention of
    the sidecar's ``duals.convention`` (Clarabel's ``z`` and SCS's ``y`` for npz)."""
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    _check_meta(disc, meta)
    x, y = _vector(x, "x", meta["variables"], meta.get("n_variables")), _vector(y, "y", meta["rows"], None)
    var, rows, un = meta["variables"], meta["rows"], meta["units"]
    S, n, k = un["stress"], disc.n_elements, disc.k
    w = element_weights(disc)

    def part(v, rng):
        return v[rng[0]:rng[1]]

    if meta["form"] == "S":
        sigma = S * part(x, var["tau"]).reshape(n, k) / w[:, None]
        xi = S * part(x, var["xi"]) / w if var["xi"] is not None else np.zeros(n)
        to_u = meta["duals"]["dual_to_displacement"]
        return ExportAnswer(sigma, xi, to_u * part(y, rows["equilibrium"]), float(to_u * y[rows["force"][0]]),
                            un["force"] * part(x, var["lam"]))
    m = disc.material
    u_free = un["displacement"] * part(x, var["v"])
    p = (S / un["E"]) * (part(x, var["p"]).reshape(n, k - 1) @ deviatoric_basis(k).T) / w[:, None]
    kappa = (S / un["E"]) * part(x, var["kappa"]) / w
    sigma = (disc.strain(u_free) - p) @ m.stiffness(disc.dim)
    return ExportAnswer(sigma, m.hardening * kappa, u_free, float(un["displacement"] * x[var["V"][0]]),
                        meta["duals"]["dual_to_force"] * part(y, rows["contact"]))


def solution_from_answer(disc: Discretization, answer: ExportAnswer, method: str = "export",
                         message: str = "") -> Solution:
    """The certified :class:`~elastoplast.certificate.solution.Solution` of an answer
    (``status`` CONVERGED: the certificate's residuals, not the status, judge it)."""
    return make_solution(disc, method=method, status=Status.CONVERGED, sigma=answer.sigma, xi=answer.xi,
                         u_free=answer.u_free, U=answer.U, contact_force=answer.contact_force, iterations=0,
                         timings={}, message=message)
