"""Where a recorded result came from: package version, commit, machine, command.

Every benchmark result and every ``summary.json`` carries :func:`stamp`, so a
figure can always be traced to the code that produced it.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any, Callable


def _git(*args: str, cwd: Path) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def source_commit() -> tuple[str | None, bool | None]:
    """``(commit, dirty)`` of the checkout the package is imported from, or
    ``(None, None)`` for an installed copy outside a git work tree."""
    root = Path(__file__).resolve().parents[1]
    commit = _git("rev-parse", "HEAD", cwd=root)
    if commit is None:
        return None, None
    status = _git("status", "--porcelain", "--untracked-files=no", cwd=root)
    return commit, bool(status)


#: ``(commit, dirty)`` taken when a benchmark script started (:func:`record_parser`):
#: a record is stamped with the state of the code that ran, not with the state after
#: the script has written its own plots into the tracked tree.
_SOURCE_AT_START: tuple[str | None, bool | None] | None = None


def stamp(command: str | None = None) -> dict[str, Any]:
    """The provenance of a result being recorded now.

    ``command`` defaults to the running process's command line. The commit and
    its ``dirty`` flag are those at the start of the script when it called
    :func:`record_parser`, else those of now.
    """
    from elastoplast import __version__

    commit, dirty = _SOURCE_AT_START if _SOURCE_AT_START is not None else source_commit()
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        cores = os.cpu_count()
    return {
        "package_version": __version__,
        "commit": commit,
        "dirty": dirty,
        "date": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "python": platform.python_version(),
        "machine": f"{platform.machine()}, {cores} cores",
        "command": command if command is not None else " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
    }


def stamp_line(s: dict[str, Any]) -> str:
    """One Markdown line for the head of a report."""
    commit = (s.get("commit") or "unknown")[:10] + (" (uncommitted changes)" if s.get("dirty") else "")
    return (f"Recorded by `{s.get('command')}` on {s.get('date')}: elastoplast {s.get('package_version')}, "
            f"commit {commit}, Python {s.get('python')}, {s.get('machine')}.")


# ----------------------------------------------------------------------------
# benchmark records: <name>.json with a top-level stamp, <name>.md opening with it
# (the convention of benchmarks/README.md, one piece of code for every script)
# ----------------------------------------------------------------------------

#: the head line of a report whose figures were recorded before stamps existed
UNSTAMPED_LINE = ("Recorded before stamping (commit unknown): the package version and commit that "
                  "produced these figures were not recorded.")


def script_command() -> str:
    """The running command as ``python <script> <args>``, the script's path taken
    relative to the repository when it lies inside it (as the READMEs write it)."""
    script = Path(sys.argv[0]).resolve()
    root = Path(__file__).resolve().parents[1]
    shown = script.relative_to(root) if script.is_relative_to(root) else Path(sys.argv[0])
    return " ".join(["python", shown.as_posix(), *sys.argv[1:]])


def record_parser(doc: str, quick: str = "small cases") -> argparse.ArgumentParser:
    """The command line every benchmark script shares: ``--quick`` (``quick``
    describes what it runs), ``--out DIR`` and ``--report``; ``doc`` is the
    script's docstring, shown by ``--help``. Remembers the source's commit and
    state now, for the stamp of what the script records."""
    global _SOURCE_AT_START
    _SOURCE_AT_START = source_commit()
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
    from elastoplast.io.output import json_default

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
               run: Callable[[str, Path], dict[str, Any]], render: Callable[[dict[str, Any]], str],
               plots: Callable[[dict[str, Any], Path], None] | None = None, argv=None,
               study: str | None = None) -> int:
    """The ``main()`` of a benchmark script: parse ``--quick``/``--out``/``--report``
    (:func:`record_parser`), run ``run(mode, out)`` (mode ``"quick"`` or ``"full"``)
    timed into ``total_time_s``, stamp and write the record (a folder's
    ``results.json``/``REPORT.md``, or ``<study>.json``/``<study>.md`` for a side
    study), then draw ``plots(results, out)``; with ``--report`` only the report and
    the plots again."""
    import time

    args = record_parser(doc, quick).parse_args(argv)
    out = record_dir(topic, args.quick, args.out)
    if args.report:
        res = rewrite_report(out, title, render, study=study)
    else:
        mode = "quick" if args.quick else "full"
        t0 = time.perf_counter()
        print(f"{label}, {mode} mode -> {out}", flush=True)
        res = run(mode, out)
        res["total_time_s"] = round(time.perf_counter() - t0, 1)
        res = write_record(out, res, title, render, study=study)
    if plots is not None:
        plots(res, out)
    if not args.report:
        print(f"done in {res['total_time_s']} s", flush=True)
    return 0


def run_child(script: str | Path, spec: Any, flag: str = "--child", cwd: str | Path | None = None) -> dict[str, Any]:
    """Run ``python script flag JSON(spec)`` in a fresh process (its own peak memory) and
    return the JSON object on the last line of its output, or ``{"error": ...}`` with
    the last line of its stderr when it failed."""
    cmd = [sys.executable, str(script), flag, json.dumps(spec)]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd)
    if proc.returncode != 0:
        err = proc.stderr.strip()
        return {"error": err.splitlines()[-1] if err else f"exit {proc.returncode}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])
