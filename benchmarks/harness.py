"""What every benchmark script shares: its command line and ``main()`` (:func:`run_record`),
its record (``<name>.json`` with a top-level stamp, ``<name>.md`` opening with it), its
child processes (:func:`run_child`) and its peak memory (:func:`peak_memory`); the
convention is that of benchmarks/README.md.

A script under ``benchmarks/<topic>/`` puts this folder on the path and imports it::

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    from harness import run_record  # noqa: E402
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable

from elastoplast.io.output import json_default
from elastoplast.io.provenance import freeze_source, stamp, stamp_line

ROOT = Path(__file__).resolve().parents[1]

#: the head line of a report whose figures were recorded before stamps existed
UNSTAMPED_LINE = ("Recorded before stamping (commit unknown): the package version and commit that "
                  "produced these figures were not recorded.")


def peak_memory() -> int:
    """Peak resident memory of this process since it started (VmHWM), in bytes (Linux).

    A case measured in a child process (:func:`run_child`) reads it there and reports
    it back: the figure is that process's alone. ``resource.getrusage`` is no
    substitute: Linux carries a parent's ``ru_maxrss`` over into its children, and
    ``RUSAGE_CHILDREN`` gives the largest of them."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise OSError("no VmHWM in /proc/self/status")


def shipped_problem(name: str, divisions) -> "Any":
    """The discretisation of ``problems/<name>.toml`` with its mesh divisions replaced."""
    import elastoplast as ep

    problems = ROOT / "problems"
    data = ep.read_toml(problems / f"{name}.toml")
    data["mesh"]["divisions"] = list(divisions)
    return ep.discretize(ep.problem_from_dict(data, base_dir=problems))


def script_command() -> str:
    """The running command as ``python <script> <args>``, the script's path taken
    relative to the repository when it lies inside it (as the READMEs write it)."""
    script = Path(sys.argv[0]).resolve()
    shown = script.relative_to(ROOT) if script.is_relative_to(ROOT) else Path(sys.argv[0])
    return " ".join(["python", shown.as_posix(), *sys.argv[1:]])


def record_parser(doc: str, quick: str = "small cases") -> argparse.ArgumentParser:
    """The command line every benchmark script shares: ``--quick`` (``quick``
    describes what it runs), ``--out DIR`` and ``--report``; ``doc`` is the
    script's docstring, shown by ``--help``."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=f"{quick}, written into quick/ unless --out is given")
    ap.add_argument("--out", help="output directory (default: the script's folder; --quick: quick/ below it)")
    ap.add_argument("--report", action="store_true",
                    help="only render the report (and plots) again from the recorded JSON")
    return ap


def record_dir(topic: str | Path, quick: bool, out: str | Path | None = None) -> Path:
    """Where a benchmark script writes: ``out`` when given, else ``<topic>/quick/``
    for a quick run (never committed), else the topic folder itself. Created."""
    path = Path(out) if out is not None else Path(topic) / "quick" if quick else Path(topic)
    path.mkdir(parents=True, exist_ok=True)
    return path


def record_paths(out_dir: str | Path, study: str | None = None) -> tuple[Path, Path]:
    """``(results.json, REPORT.md)`` of a folder's main script, or
    ``(<study>.json, <study>.md)`` of a side study."""
    out = Path(out_dir)
    if study is None:
        return out / "results.json", out / "REPORT.md"
    return out / f"{study}.json", out / f"{study}.md"


def report_text(title: str, results: dict[str, Any], body: str) -> str:
    """A report: ``# title``, the stamp line of ``results["stamp"]`` (or
    :data:`UNSTAMPED_LINE` when the record has none), then ``body``."""
    s = results.get("stamp")
    head = stamp_line(s) if s else UNSTAMPED_LINE
    return f"# {title}\n\n{head}\n\n{body.strip()}\n"


def write_record(out_dir: str | Path, results: dict[str, Any], title: str,
                 render: Callable[[dict[str, Any]], str], study: str | None = None,
                 command: str | None = None) -> dict[str, Any]:
    """Stamp ``results`` now and write the JSON record and its Markdown report.

    ``render(results)`` gives the report's body (tables and key ratios of the
    JSON). ``command`` defaults to :func:`script_command`. Returns the stamped
    results as written.
    """
    stamped = {"stamp": stamp(command if command is not None else script_command()), **results}
    json_path, md_path = record_paths(out_dir, study)
    json_path.write_text(json.dumps(stamped, indent=1, default=json_default) + "\n")
    md_path.write_text(report_text(title, stamped, render(stamped)))
    return stamped


def rewrite_report(out_dir: str | Path, title: str, render: Callable[[dict[str, Any]], str],
                   study: str | None = None) -> dict[str, Any]:
    """Render the Markdown report again from the recorded JSON (whatever stamp it
    has, or none); the JSON is left as it is. Returns the recorded results."""
    json_path, md_path = record_paths(out_dir, study)
    results = json.loads(json_path.read_text())
    md_path.write_text(report_text(title, results, render(results)))
    return results


def run_record(doc: str, quick: str, topic: str | Path, title: str, label: str,
               run: Callable[..., dict[str, Any]], render: Callable[[dict[str, Any]], str],
               plots: Callable[[dict[str, Any], Path], None] | None = None, argv=None,
               study: str | None = None, child: Callable[[Any], dict[str, Any]] | None = None,
               options: dict[str, dict[str, Any]] | None = None) -> int:
    """The ``main()`` of a benchmark script: parse ``--quick``/``--out``/``--report``
    (:func:`record_parser`), take the source's state (:func:`freeze_source`), run
    ``run(mode, out)`` (mode ``"quick"`` or ``"full"``) timed into ``total_time_s``,
    stamp and write the record (a folder's ``results.json``/``REPORT.md``, or
    ``<study>.json``/``<study>.md`` for a side study), then draw ``plots(results, out)``;
    with ``--report`` only the report and the plots again.

    ``options``: the script's own arguments, ``{name: add_argument keywords}``, whose
    values ``run`` receives as keywords. ``child``: the entry point of the script's
    child processes; ``--child JSON`` (:func:`run_child`) only prints ``child(spec)``
    of the decoded JSON as the last line of output.
    """
    ap = record_parser(doc, quick)
    if child is not None:
        ap.add_argument("--child", help=argparse.SUPPRESS)
    extra = [ap.add_argument(name, **kw).dest for name, kw in (options or {}).items()]
    args = ap.parse_args(argv)
    if child is not None and args.child is not None:
        print(json.dumps(child(json.loads(args.child)), default=json_default), flush=True)
        return 0
    freeze_source()
    out = record_dir(topic, args.quick, args.out)
    if args.report:
        res = rewrite_report(out, title, render, study=study)
    else:
        mode = "quick" if args.quick else "full"
        t0 = time.perf_counter()
        print(f"{label}, {mode} mode -> {out}", flush=True)
        res = run(mode, out, **{k: getattr(args, k) for k in extra})
        res["total_time_s"] = round(time.perf_counter() - t0, 1)
        res = write_record(out, res, title, render, study=study)
    if plots is not None:
        plots(res, out)
    if not args.report:
        print(f"done in {res['total_time_s']} s", flush=True)
    return 0


def run_child(script: str | Path, spec: Any, cwd: str | Path | None = None, check: bool = False) -> dict[str, Any]:
    """Run ``python script --child JSON(spec)`` in a fresh process (so that its
    :func:`peak_memory` is its own) and return the JSON object on the last line of its
    output, or ``{"error": ...}`` with the last line of its stderr when it failed
    (with ``check``: stop with that error instead)."""
    cmd = [sys.executable, str(script), "--child", json.dumps(spec)]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd)
    if proc.returncode == 0:
        return json.loads(proc.stdout.strip().splitlines()[-1])
    err = proc.stderr.strip()
    err = err.splitlines()[-1] if err else f"exit {proc.returncode}"
    if check:
        raise SystemExit(f"{Path(script).name} {json.dumps(spec)}: {err}")
    return {"error": err}
