"""``elastoplast check PROBLEM.toml ANSWER [--tol T] [--bounds] [--out DIR]``: the KKT
certificate of an answer computed anywhere (another program, another method, by hand).

ANSWER is an ``.npz`` (arrays ``u``, ``U``, optionally ``sigma`` and ``xi``) or a ``.vtu``
with its U; the formats and the node order are stated in :mod:`elastoplast.io.answers`.

The answer is read by :func:`~elastoplast.io.answers.read_answer` and judged like every
built-in method's (:func:`~elastoplast.studies.answer.certify_answer`). ``--bounds`` adds the continuum upper bound of this displacement field
(:func:`~elastoplast.bounds.upper.upper_bound`), the lower bound of the equilibrium
element and their energy and U brackets, as ``elastoplast bounds`` prints them.

Exit codes: 0 certified (with ``--bounds``: and the bracket certified), 1 not certified,
2 bad input (:class:`~elastoplast.errors.InputError`: one line naming the array, e.g.
``ANSWER.u: expected (861, 2), got (861, 3)``). Nothing is written unless ``out``
is given.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any, Mapping

from elastoplast.certificate.kkt import KKTResiduals
from elastoplast.certificate.solution import Solution
from elastoplast.cli.exits import EXIT_NOT_CONVERGED, EXIT_OK
from elastoplast.cli.printing import discretize_file, problem_line
from elastoplast.errors import InputError, figure
from elastoplast.io.answers import FIELD, read_answer
from elastoplast.limits import as_path, check_input_file, shown
from elastoplast.options import SolverOptions
from elastoplast.studies.answer import answer_bounds, certify_answer


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


def residual_lines(kkt: KKTResiduals, tol: float) -> list[str]:
    """One line per residual: name, value, the comparison with ``tol``, ok or FAIL."""
    width = max(len(name) for name in kkt.as_dict())
    return [f"{name:<{width}}  {value:.2e} {'<=' if value <= tol else '> '} {tol:.3g}  "
            f"{'ok' if value <= tol else 'FAIL'}" for name, value in kkt.as_dict().items()]


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
    if bounds:  # refused before the check runs, as the bounds would refuse it after
        from elastoplast.bounds.lower import SEQUENCE_MEMORY_FACTOR, LowerBoundOptions, check_lower_bound_size

        check_lower_bound_size(disc, LowerBoundOptions(), factor=SEQUENCE_MEMORY_FACTOR)
    if not quiet:
        stresses = "sigma, xi as given" if answer["sigma"] is not None else "stresses by the return mapping of u"
        print(problem_line(problem_path, disc, f"checking {Path(answer_path).name} ({stresses}), tol {tol:g}"
                                                + ("; then the bounds" if bounds else "")), file=sys.stderr)
    sol = certify_answer(disc, answer, tol, seconds=time.perf_counter() - t0)
    report = answer_bounds(disc, sol) if bounds else None  # before any output: it may refuse the input (load.force)
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
        from elastoplast.studies.results import write_results

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
