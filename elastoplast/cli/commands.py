"""The commands of the command line, one function each: check the input, run, print one summary line, return the exit code."""

from __future__ import annotations
import argparse
import contextlib
import sys
import tomllib
import warnings
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, Mapping
from elastoplast.cli.exits import EXIT_NOT_CONVERGED, EXIT_OK, outcome
from elastoplast.errors import FIELD_WIDTH, InputError, elide, figure
from elastoplast.cli.loading_path import has_depth, has_path, refuse_path, solve_depth_command, solve_path_command
from elastoplast.cli.printing import discretize_file, problem_line





#: command-line shorthands for solver options: flag -> option name
OPTION_FLAGS = {"--tol": "tol", "--max-iter": "max_iter", "--rho": "rho", "--time-limit": "time_limit"}


def default_problem_path() -> Path:
    """The built-in default problem shipped with the package."""
    return Path(str(resources.files("elastoplast") / "data" / "default.toml"))


def _parse_value(text: str) -> Any:
    """A TOML value (``1e-8``, ``true``, ``"splu"``), or the bare text as a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def command_line_options(args: argparse.Namespace) -> dict[str, Any]:
    """The solver options given on the command line, keyed by option name."""
    options: dict[str, Any] = {}
    for item in args.option:
        name, sep, value = item.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name:
            raise InputError("--option", f"expected NAME=VALUE, got {item!r}")
        options[name] = _parse_value(value.strip())
    for flag, name in OPTION_FLAGS.items():
        value = getattr(args, name)
        if value is not None:
            options[name] = value
    return options


def _flag_names(exc: InputError) -> InputError:
    """Name a command-line option by its flag (``--max-iter``, not ``max_iter``)."""
    flags = {name: flag for flag, name in OPTION_FLAGS.items()}
    return InputError(flags.get(exc.field, f"--option {exc.field}"), exc.message)


def _setup(args: argparse.Namespace, solver: bool = True):
    """What every command on one problem starts with: the problem file (or the
    built-in default), its ``[solver]`` table and the command-line options, all
    checked, and ``--out`` checked, before any work. Returns ``(path, data,
    method, options)``; with ``solver`` False (``limit``, and ``adapt``, which
    reads the table itself) the ``[solver]`` table is not read and both are None."""
    from elastoplast.io.output import check_output_dir
    from elastoplast.problem.definition import read_toml
    from elastoplast.solvers.registry import method_options

    path = Path(args.problem) if args.problem else default_problem_path()
    data = read_toml(path)
    method = opts = None
    if solver:
        method, options = _file_solver(data.get("solver", {}), args.method)
        given = command_line_options(args)
        try:
            method_options(method, given)  # the flags alone, named as flags
        except InputError as exc:
            raise _flag_names(exc) from None
        opts = method_options(method, {**options, **given, "progress": not args.quiet}, prefix="solver.")
    check_output_dir(args.out, "--out")
    return path, data, method, opts


def _file_solver(table: Any, flag: str | None) -> tuple[str, dict[str, Any]]:
    """The method and the file's ``[solver]`` options for it, checked and named as
    written (``solver.tol``). ``flag``, the ``--method`` given, wins over the file's
    method; when it names another method, the file's options that method does not
    have are dropped, each with a note on stderr, and the others still apply."""
    from elastoplast.solvers.registry import DEFAULT_METHOD, get_method, solver_settings

    if flag is None or not isinstance(table, Mapping):
        return solver_settings(table)  # a [solver] that is no table is refused here
    method = get_method(flag, "--method")
    if table.get("method", DEFAULT_METHOD) != method.name:
        get_method(table.get("method", DEFAULT_METHOD), "solver.method")  # the file's own method, checked
        specs = method.options.specs()
        for key in table:
            if key != "method" and key not in specs:
                print(f"note: solver.{elide(key, FIELD_WIDTH)}: not an option of {method.name} (--method), ignored",
                      file=sys.stderr)
        table = {k: v for k, v in table.items() if k in specs}
    return solver_settings({**table, "method": method.name})


#: the names the library gives the command line's arguments (run_campaign, compare), by command
_CLI_NAMES = {
    "campaign": {"out": "--out", "store": "--out", "workers": "--workers", "scheduler": "--scheduler"},
    "compare": {"store": "STORE", "out": "--out", "reference_method": "--reference-method", "workers": "--workers",
                "scheduler": "--scheduler"},
    "export": {"out": "--out", "path": "--out", "format": "--format", "form": "--form", "energy": "--energy"},
}


@contextlib.contextmanager
def _named_as_flags(command: str) -> Iterator[None]:
    """Re-raise an InputError naming a library argument (``out``, ``store``,
    ``reference_method``, ``workers``, ``scheduler``) under the command line's name for it."""
    try:
        yield
    except InputError as exc:
        names = _CLI_NAMES[command]
        if exc.field in names:
            raise InputError(names[exc.field], exc.message) from None
        raise


def _discretize(path: Path, data: dict, quiet: bool, what: str):
    disc = discretize_file(path, data)
    if not quiet:
        print(problem_line(path, disc, what), file=sys.stderr)
    return disc


def _solve(args: argparse.Namespace) -> int:
    from elastoplast.studies.results import write_results
    from elastoplast.solvers.registry import solve

    path, data, method, opts = _setup(args)
    if has_path(data):  # a loading path: every step, its files (cli/loading_path.py)
        return solve_path_command(args, path, data, method, opts)
    if has_depth(data):  # depth control: the force found (cli/paths.py)
        return solve_depth_command(args, path, data, method, opts)
    disc = _discretize(path, data, args.quiet, f"method {method}")
    sol = solve(disc, method, opts)
    data = write_results(args.out, disc, sol, field="--out")
    print(f"{sol.status.value}: U = {figure(sol.U, '.6g')}, max contact pressure = "
          f"{figure(data['max_contact_pressure'], '.6g')}, contact radius = {figure(data['contact_radius'], '.4g')}, "
          f"plastic volume = {figure(100 * data['plastic_volume_fraction'], '.2f')}%")
    print(f"KKT worst residual {figure(sol.kkt.worst, '.2e')}, duality gap {figure(sol.duality_gap, '.2e')}, "
          f"{sol.iterations} iterations, {sol.time_s:.2f} s -> {Path(args.out) / 'summary.json'}")
    return outcome(sol.converged, f"not converged: {sol.message}")


def _bounds(args: argparse.Namespace) -> int:
    from elastoplast.references.certified import certified_bounds
    from elastoplast.bounds.bracket import check_lower_bound_fits, gap_fields, lower_kind
    from elastoplast.bounds.lower import SEQUENCE_MEMORY_FACTOR, LowerBoundOptions
    from elastoplast.certificate.solution import Status
    from elastoplast.studies.results import write_results
    from elastoplast.solvers.registry import check_solvable, solve

    path, data, method, opts = _setup(args)
    refuse_path(data, "bounds")
    disc = _discretize(path, data, args.quiet, f"P1 solution by {method}, then the bounds")
    # before the solve; the U bracket runs two more lower bounds in this process
    with _lower_flag():
        lower_options = LowerBoundOptions.build({"kind": args.lower or "auto", "descent": args.descent})
        kind = check_lower_bound_fits(disc, lower_options, factor=1.0 if args.no_bracket else SEQUENCE_MEMORY_FACTOR)
    descent_unused(args.descent, disc.material.hardening, args.lower, kind)
    method, opts = _method_that_fits(args, data, disc, method, opts)
    check_solvable(disc, method, opts)
    sol = solve(disc, method, opts)
    if sol.status is Status.INFEASIBLE:
        raise InputError("load.force", f"{disc.force:g} is above the limit load ({sol.message}): the problem has "
                                       "no solution to bound; 'elastoplast limit' brackets the limit load")
    if not sol.converged:
        print(f"warning: the P1 solution did not converge ({sol.message}); its upper bound stays valid, only looser",
              file=sys.stderr)
    with lower_bound_bar(args.quiet, kind) as progress:
        report = certified_bounds(disc, sol, method, lower_options=lower_options, bracket=not args.no_bracket,
                                  progress=progress, options=opts)
    b = report.bounds
    write_results(args.out, disc, sol, extra=report.as_dict(), field="--out", **gap_fields(disc, b))
    bracket = "" if args.no_bracket else (f"; U in [{figure(report.U_lower, '.6g')}, "
                                          f"{figure(report.U_upper, '.6g')}]")
    used = {"local": "local field", "global": "global program"}[lower_kind(report.lower)]
    if disc.problem.axisymmetric and args.lower in (None, "auto"):
        used += ", the only one in axisymmetry so far"
    print(f"energy in [{figure(b.energy_lower, '.8g')}, {figure(b.energy_upper, '.8g')}] (relative gap "
          f"{figure(b.energy_gap_rel, '.2e')}, lower bound: {used}){bracket} (discrete U = {figure(sol.U, '.6g')}); "
          f"stress error <= {figure(b.stress_error_bound, '.4g')} ({figure(100 * b.stress_error_bound_rel, '.2f')}%); "
          f"{'certified' if report.certified else 'NOT certified'} -> {Path(args.out) / 'summary.json'}")
    return outcome(report.certified, f"not certified: upper: {report.upper.message}; lower: {report.lower.message}")


def _method_that_fits(args: argparse.Namespace, data: dict, disc, method: str, opts):
    """``bounds`` with no method named (no ``--method``, none in ``[solver]``) on a mesh
    beyond the conic reference's size: Newton instead, as adapt's default, with a note."""
    from elastoplast.solvers.registry import CONIC_MAX_ELEMENTS, method_options

    table = data.get("solver", {})
    named = args.method is not None or (isinstance(table, Mapping) and "method" in table)
    limit = CONIC_MAX_ELEMENTS[disc.dim]
    if named or not method.startswith("conic") or disc.n_elements <= limit:
        return method, opts
    print(f"note: {disc.n_elements:,} elements is beyond the conic reference's {limit:,} in {disc.dim}D: the P1 "
          "solution by newton (--method chooses another)", file=sys.stderr)
    _, options = _file_solver(table, "newton")
    return "newton", method_options("newton", {**options, **command_line_options(args), "progress": not args.quiet},
                                    prefix="solver.")


def descent_unused(descent: int | None, hardening: float, lower: str | None, kind: str | None) -> None:
    """``--descent`` belongs to the local lower bound: refused where it can do nothing
    (H = 0, or ``--lower global`` asked for), noted where ``auto`` chose the global
    program (``kind``; None: not known yet, as in adapt, where the size decides per mesh)."""
    if descent is None:
        return
    if hardening == 0:
        raise InputError("--descent", "does nothing with hardening = 0: the lower bound is then the global program, "
                                      "which has no descent (leave --descent out)")
    if lower == "global":
        raise InputError("--descent", "does nothing with --lower global: the descent is the local lower bound's "
                                      "(use --lower local or auto, or leave --descent out)")
    if kind == "global":
        warnings.warn(f"--descent {descent} does nothing here: on this mesh the lower bound is the global program "
                      "(--lower auto), which has no descent")


@contextlib.contextmanager
def _lower_flag() -> Iterator[None]:
    """Name the lower-bound options by their flags (``--lower``, ``--descent``)."""
    try:
        yield
    except InputError as exc:
        if exc.field in ("kind", "lower_options.kind"):
            raise InputError("--lower", exc.message) from None
        if exc.field in ("descent", "lower_options.descent"):
            raise InputError("--descent", exc.message) from None
        raise


@contextlib.contextmanager
def lower_bound_bar(quiet: bool, kind: str):
    """A progress bar on stderr for the lower bounds (the local bound reports as it goes),
    and the ``progress(fraction, what)`` that moves it."""
    from tqdm.auto import tqdm

    bars = []  # opened at the first report, after the upper bound's solves and their own bars

    def progress(fraction: float, what: str) -> None:
        if not bars:
            bars.append(tqdm(total=100, desc=f"{kind} lower bound", unit="%", disable=quiet, file=sys.stderr,
                             leave=False, bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}"))
        bar = bars[0]
        bar.n = round(100 * fraction)
        bar.set_description_str(elide(what, 60), refresh=False)
        bar.refresh()

    try:
        yield progress
    finally:
        for bar in bars:
            bar.close()


def _limit(args: argparse.Namespace) -> int:
    from elastoplast.bounds.limit_load import LimitOptions, limit_load
    from elastoplast.bounds.lower import LowerBoundOptions
    from elastoplast.io.output import json_text, staged_output

    path, data, _, _ = _setup(args, solver=False)  # the limit load has no [solver]: its programs are Clarabel's
    refuse_path(data, "limit")
    if "solver" in data:
        print("note: solver: the limit load's two programs are Clarabel's (--order, --time-limit set them); the "
              "[solver] table is not used", file=sys.stderr)
    warnings.filterwarnings("ignore", message=r".*hardening = 0 is perfect plasticity")  # what 'limit' is for
    given = {k: v for k, v in (("order", args.order), ("time_limit", args.time_limit)) if v is not None}
    try:
        options = LimitOptions.build(given)
    except InputError as exc:
        raise InputError(f"--{exc.field.replace('_', '-')}", exc.message) from None
    disc = _discretize(path, data, args.quiet, "limit load bracket (H = 0)")
    bracket = limit_load(disc, options, LowerBoundOptions(time_limit=options.time_limit))
    with staged_output(args.out, "--out") as tmp:
        from elastoplast.io.provenance import stamp

        (tmp / "summary.json").write_text(json_text({**bracket.as_dict(), "provenance": stamp()}))
    print(f"{bracket.F_lower:.6g} <= F_c <= {bracket.F_upper:.6g} (ratio {bracket.ratio:.4f}); "
          f"{'certified' if bracket.certified else 'NOT certified'} -> {Path(args.out) / 'summary.json'}")
    if bracket.message:
        print(bracket.message, file=sys.stderr)
    return EXIT_OK if bracket.certified else EXIT_NOT_CONVERGED


def _adapt(args: argparse.Namespace) -> int:
    from elastoplast.adapt.loop import check_adaptable, check_lower_available
    from elastoplast.adapt.records import AdaptOptions
    from elastoplast.cli.adapt import run_adapt_command
    from elastoplast.solvers.registry import get_method

    path, data, _, _ = _setup(args, solver=False)
    refuse_path(data, "adapt")
    table = data.get("solver", {})
    if not isinstance(table, Mapping):
        raise InputError("solver", f"must be a table, got {type(table).__name__}")
    # of the file's [solver] table, the method and the P1 tolerance apply; nothing is dropped silently
    unused = [f"solver.{elide(k, FIELD_WIDTH)}" for k in table if k not in ("method", "tol")]
    if unused:
        warnings.warn(f"{', '.join(unused)}: not used by adapt, which sets its own P1 solves (of [solver], method "
                      "and tol apply)")
    if "method" in table:
        get_method(table["method"], "solver.method")  # the file's, checked even where --method wins
    if args.method is not None:
        method, method_field = get_method(args.method, "--method").name, "--method"
    else:  # default Newton: the fastest P1 solver (benchmarks/methods)
        method, method_field = table.get("method", AdaptOptions().method), "solver.method"
    from_file = {"tol": table["tol"]} if "tol" in table else {}
    AdaptOptions.build(from_file, prefix="solver.")  # the range of adapt's P1 tolerance, named as written
    given = {k: v for k, v in (("rtol", args.rtol), ("theta", args.theta), ("min_growth", args.min_growth),
                               ("max_elements", args.max_elements),
                               ("time_limit", args.time_limit), ("bracket", args.bracket), ("lower", args.lower),
                               ("lower_descent", args.descent))
             if v is not None}
    given = {**from_file, **given}
    if args.no_uniform:
        given["compare_uniform"] = False
    try:
        options = AdaptOptions.build({**given, "method": method, "progress": not args.quiet})
    except InputError as exc:
        flags = {"method": method_field, "lower_descent": "--descent"}
        raise InputError(flags.get(exc.field, f"--{exc.field.replace('_', '-')}"), exc.message) from None
    disc = _discretize(path, data, args.quiet, f"adaptive refinement to rtol {options.rtol:g}")
    check_adaptable(disc.problem)
    try:
        check_lower_available(disc.problem, options)
    except InputError as exc:
        raise InputError("--lower", exc.message) from None
    descent_unused(args.descent, disc.material.hardening, args.lower, None)
    return EXIT_OK if run_adapt_command(disc.problem, options, args.out) else EXIT_NOT_CONVERGED


def _campaign(args: argparse.Namespace) -> int:
    from elastoplast.studies.campaign import load_campaign, run_campaign
    from elastoplast.io.store import Store

    campaign = load_campaign(args.campaign)
    with _named_as_flags("campaign"):
        run = run_campaign(campaign, args.out, scheduler=args.scheduler, n_workers=args.workers,
                           progress=not args.quiet, retry_failed=args.retry_failed)
    ids = {c.case_id for c in campaign.cases}
    statuses = [r["status"] for r in Store(args.out).rows() if r["id"] in ids]
    failed = sum(s != "converged" for s in statuses)
    print(f"{campaign.name}: {len(ids)} cases, {len(run.statuses)} run, {len(run.skipped)} already stored; "
          f"{len(statuses) - failed} converged, {failed} failed -> {Path(args.out) / 'index.sqlite'}")
    if campaign.n_duplicates:
        print(f"note: {campaign.n_duplicates} sweep point(s) resolved to the same input as an earlier one", file=sys.stderr)
    for case_id, status in run.failed.items():
        print(f"failed: {case_id[:12]} {status}: {Store(args.out).row(case_id)['error']}", file=sys.stderr)
    return EXIT_OK if failed == 0 and len(statuses) == len(ids) else EXIT_NOT_CONVERGED


def _compare(args: argparse.Namespace) -> int:
    from elastoplast.studies.compare import compare
    from elastoplast.cli.suite import suite_command
    from elastoplast.studies.suite import is_suite_dir
    from elastoplast.solvers.registry import method_options

    if is_suite_dir(args.store):  # a folder of problem files: performance profiles (cli/suite.py)
        return suite_command(args, command_line_options(args))
    if len(args.method) > 1:
        raise InputError("--method", "a campaign store is compared one method at a time")
    args.method = args.method[0]
    options = command_line_options(args)
    try:
        method_options(args.method, options)
    except InputError as exc:
        raise _flag_names(exc) if exc.field != "method" else InputError("--method", exc.message) from None
    with _named_as_flags("compare"):
        report = compare(args.store, args.method, options=options, reference_method=args.reference_method,
                         out=args.out, scheduler=args.scheduler, n_workers=args.workers, progress=not args.quiet)
    print(report.markdown(), end="")
    out = Path(args.out) if args.out else Path(args.store) / f"compare-{report.method}"
    print(f"-> {out / 'report.md'}, {out / 'compare.png'}, {out / 'compare.json'}", file=sys.stderr)
    return EXIT_OK if report.summary["n_converged"] == report.summary["n_cases"] else EXIT_NOT_CONVERGED


def _options(args: argparse.Namespace) -> int:
    """``elastoplast options [METHOD]``: every option behind ``--option NAME=VALUE``,
    read from the options classes (their type, default and admitted range)."""
    import dataclasses

    from elastoplast.solvers.registry import METHODS, get_method

    chosen = [get_method(args.method, "METHOD")] if args.method is not None else list(METHODS.values())
    by_class: dict[type, list] = {}
    for m in chosen:  # the conic methods share one class: listed once
        by_class.setdefault(m.options, []).append(m)
    print("Set with --option NAME=VALUE (the value in TOML syntax), a [solver] table or a campaign axis "
          "\"solver.NAME\"; --tol, --max-iter, --rho and --time-limit are shorthands.")
    for cls, methods in by_class.items():
        defaults = {f.name: f.default for f in dataclasses.fields(cls)}
        rows = [("option", "type", "default", "admitted", "meaning")]
        rows += [(name, _kind_text(spec), _toml_text(defaults[name]), _range_text(spec), spec.doc)
                 for name, spec in cls.specs().items()]
        widths = [max(len(r[i]) for r in rows) for i in range(4)]
        print(f"\n{', '.join(m.name for m in methods)} ({cls.__name__}): {'; '.join(m.summary for m in methods)}")
        for row in rows:
            print("  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths)) + "  " + row[4])
    return EXIT_OK


def _kind_text(spec) -> str:
    names = {float: "number", int: "integer", bool: "boolean", str: "string"}
    return names.get(spec.kind, f"{spec.kind.__name__} (Python only)")


def _toml_text(value: Any) -> str:
    """``value`` as it is written after ``--option NAME=``; ``none`` for None."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return f"{value:g}" if isinstance(value, float) else str(value)


def _range_text(spec) -> str:
    """What an option admits: its choices, or its interval (``(0, inf)``)."""
    if spec.choices is not None:
        return " | ".join(f'"{c}"' for c in spec.choices)
    if spec.kind is bool:
        return "true | false"
    if spec.kind not in (int, float):
        return "-"
    text = (lambda v: str(int(v))) if spec.kind is int else (lambda v: f"{v:g}")
    lo = "(-inf" if spec.lo is None else f"{'(' if spec.lo_open else '['}{text(spec.lo)}"
    hi = "inf)" if spec.hi is None else f"{text(spec.hi)}]"
    return f"{lo}, {hi}"


def _check(args: argparse.Namespace) -> int:
    from elastoplast.cli.check import run_check
    from elastoplast.problem.definition import read_toml

    refuse_path(read_toml(args.problem), "check")
    return run_check(args.problem, args.answer, tol=args.tol, bounds=args.bounds, out=args.out, quiet=args.quiet)


def _export(args: argparse.Namespace) -> int:
    from elastoplast.io.export import check_export_options, export, limit_load_note
    from elastoplast.io.export_files import check_export_path
    from elastoplast.problem.definition import read_toml

    path = Path(args.problem) if args.problem else default_problem_path()
    data = read_toml(path)
    refuse_path(data, "export")
    mesh = data.get("mesh") if isinstance(data, dict) else None
    mesh_file = mesh.get("file") if isinstance(mesh, dict) else None
    protect = [path] + ([path.parent / mesh_file] if isinstance(mesh_file, str) else [])
    with _named_as_flags("export"):  # the output file judged before any work
        check_export_options(args.format, args.form, args.energy)
        check_export_path(args.out, args.format, "path", protect)
    disc = _discretize(path, data, args.quiet, f"export of ({args.form}) as {args.format}")
    note = limit_load_note(disc)
    if note:
        print(f"note: {note}", file=sys.stderr)
    with _named_as_flags("export"):
        info = export(disc, args.out, format=args.format, form=args.form, energy=args.energy, protect=protect)
    print(info.line())
    return EXIT_OK


COMMANDS = {"solve": _solve, "check": _check, "bounds": _bounds, "limit": _limit, "adapt": _adapt, "campaign": _campaign,
            "compare": _compare, "options": _options, "export": _export}
