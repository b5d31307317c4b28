"""Where a recorded result came from: package version, commit, machine, command.

Every benchmark result and every ``summary.json`` carries :func:`stamp`, so a
figure can always be traced to the code that produced it. The benchmark scripts
write their records with the harness in ``benchmarks/harness.py``.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any


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


#: ``(commit, dirty)`` taken by :func:`freeze_source` when a benchmark script started:
#: a record is stamped with the state of the code that ran, not with the state after
#: the script has written its own plots into the tracked tree.
_SOURCE_AT_START: tuple[str | None, bool | None] | None = None


def freeze_source() -> None:
    """Take the commit and its ``dirty`` flag now, for every later :func:`stamp` of
    this process (a benchmark script calls this as it starts)."""
    global _SOURCE_AT_START
    _SOURCE_AT_START = source_commit()


def stamp(command: str | None = None) -> dict[str, Any]:
    """The provenance of a result being recorded now.

    ``command`` defaults to the running process's command line. The commit and
    its ``dirty`` flag are those taken by :func:`freeze_source`, else those of now.
    """
    from elastoplast.version import __version__

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
