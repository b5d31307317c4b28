"""The files of a command's run: ``solution.vtu``, ``summary.json`` and, for iterative methods, ``convergence.png``, written together into a staged folder."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from elastoplast.certificate.indentation import indentation_summary
from elastoplast.certificate.solution import Solution, summary
from elastoplast.plots.figures import plot_convergence
from elastoplast.fem.discretize import Discretization
from elastoplast.io.output import json_text, staged_output, write_vtu
from elastoplast.io.revolve import write_revolved_solution


def write_results(out_dir: str | Path, disc: Discretization, sol: Solution, extra: dict[str, Any] | None = None,
                  *, field: str = "out", **vtu: Any) -> dict:
    """Write ``solution.vtu``, ``summary.json`` and (for iterative methods)
    ``convergence.png`` into ``out_dir``, which then holds nothing else but the
    marker (:func:`staged_output`; errors name ``field``); returns the summary.
    ``vtu``: more data for :func:`write_vtu` (``cell_data``, ``facets``)."""
    with staged_output(out_dir, field) as tmp:
        return write_files(tmp, disc, sol, extra, **vtu)


def write_files(folder: Path, disc: Discretization, sol: Solution, extra: dict[str, Any] | None = None,
                **vtu: Any) -> dict:
    """The files of :func:`write_results`, written into an existing folder; for an
    axisymmetric problem also ``solution_3d.vtu``, the revolved view."""
    from elastoplast.io.provenance import stamp

    write_vtu(folder / "solution.vtu", disc, sol, **vtu)
    data = summary(disc, sol)
    axisymmetric = disc.problem.axisymmetric
    data["indentation"] = indentation_summary(disc, sol, axisymmetric=axisymmetric)
    if axisymmetric:
        data["revolved_view"] = write_revolved_solution(folder / "solution_3d.vtu", disc, sol)
    if sol.history:
        data["history"] = sol.history
    if extra:
        data.update(extra)
    data["provenance"] = stamp()
    (folder / "summary.json").write_text(json_text(data))
    if sol.history:
        plot_convergence(folder / "convergence.png", sol.history, f"{sol.method}: {sol.status.value}")
    return data
