"""``elastoplast adapt``: the adaptive run with its printing, the uniform comparison, and the files it writes."""

from __future__ import annotations

import math
import time
from dataclasses import replace

from elastoplast.adapt.loop import adapt, uniform
from elastoplast.adapt.records import AdaptOptions, AdaptResult, Step, fitted_rate
from elastoplast.plots.figures import plot_gaps, plot_indicator
from elastoplast.problem.definition import Problem


def write_table(path, adaptive: AdaptResult, uniform_run: AdaptResult | None) -> str:
    """The steps as a Markdown table (adaptive, then uniform), with the fitted rates."""
    head = "| run | step | elements | lower | upper | relative gap | U lower | U upper | s | certified | lower bound |"
    lines = [head, "|" + "---|" * 11]
    for name, run in (("adaptive", adaptive), ("uniform", uniform_run)):
        if run is None:
            continue
        for s in run.steps:
            lines.append(f"| {name} | {s.step} | {s.n_elements} | {s.energy_lower:.10g} | {s.energy_upper:.10g} | "
                         f"{s.gap_rel:.3e} | {s.U_lower:.6g} | {s.U_upper:.6g} | {s.seconds:.1f} | "
                         f"{'yes' if s.certified else 'no'} | {s.lower} |")
    run_b = adaptive.bracket
    if run_b.tighter_than(adaptive.final.gap_rel):
        lines += ["", f"Bracket {run_b.line()}."]
    lines += ["", f"Stopped: {adaptive.reason}.", "",
              f"Fitted rate of the relative gap in the number of elements (gap ~ N^-p): adaptive p = "
              f"{fitted_rate(adaptive.steps):.3f}"
              + ("" if uniform_run is None else f", uniform p = {fitted_rate(uniform_run.steps):.3f}") + "."]
    text = "\n".join(lines) + "\n"
    from pathlib import Path

    Path(path).write_text(text)
    return text


def run_adapt_command(problem: Problem, options: AdaptOptions, out_dir) -> bool:
    """``elastoplast adapt``: the adaptive run (one line per step on stdout, a
    progress bar on stderr), the uniform comparison (``compare_uniform``: every
    element refined, from the same mesh up to the adaptive run's final size,
    within the same element budgets and what the adaptive run left of
    ``time_limit``: the limit bounds the whole command), and the files: ``adapt.md``/``adapt.json`` (the
    table), ``gap.png``, ``indicator.png`` (the final mesh coloured by the
    marking indicator, :func:`plot_indicator`), ``meshes/mesh_NNN.msh`` (every
    adapted mesh, gmsh format with the facet groups), and
    ``solution.vtu``/``summary.json`` of the final mesh with its bounds and local
    gaps. Returns whether the final bounds are certified and reach ``rtol``."""
    import sys

    from tqdm.auto import tqdm

    from elastoplast.bounds.bracket import gap_fields
    from elastoplast.studies.results import write_files
    from elastoplast.io.output import json_text, staged_output
    from elastoplast.io.provenance import stamp
    from elastoplast.mesh.base import write_mesh

    with staged_output(out_dir, "--out") as tmp:
        bar = tqdm(total=options.max_iter, desc="adapt", unit="mesh", disable=not options.progress, file=sys.stderr,
                   leave=False)

        def report(step: Step) -> None:
            bar.update(1)
            bar.set_postfix(gap=f"{step.gap_rel:.2e}", elements=step.n_elements)
            tqdm.write(step.line(), file=sys.stdout)

        t0 = time.perf_counter()
        run = adapt(problem, options, report=report)
        bar.close()
        uni = None
        left = None if options.time_limit is None else options.time_limit - (time.perf_counter() - t0)
        if options.compare_uniform and left is not None and left <= 0:
            print("uniform refinement skipped: the time limit is spent", file=sys.stdout)
        elif options.compare_uniform and left is not None and left < run.steps[0].seconds:  # its first mesh is the same
            print(f"uniform refinement skipped: {left:.0f} s left, its first mesh took {run.steps[0].seconds:.0f} s",
                  file=sys.stdout)
        elif options.compare_uniform:
            print("uniform refinement, for comparison:", file=sys.stdout)
            uni = uniform(problem, replace(options, time_limit=left),
                          max_elements=max(run.final.n_elements, problem.mesh.n_elements),
                          report=lambda s: tqdm.write(s.line(), file=sys.stdout))
        (tmp / "meshes").mkdir()
        for k, mesh in enumerate(run.meshes):
            write_mesh(tmp / "meshes" / f"mesh_{k:03d}.msh", mesh)
        write_table(tmp / "adapt.md", run, uni)
        (tmp / "adapt.json").write_text(json_text({
            "reason": run.reason, "options": options.persistent(),
            "adaptive": [s.as_dict() for s in run.steps], "adaptive_rate": fitted_rate(run.steps),
            "uniform": None if uni is None else [s.as_dict() for s in uni.steps],
            "uniform_rate": None if uni is None else fitted_rate(uni.steps), "provenance": stamp()}))
        plot_gaps(tmp / "gap.png", run, uni, title=f"certified gap, {problem.dim}D")
        b = run.bounds
        plot_indicator(tmp / "indicator.png", run.disc, run.solution, b)
        final = run.final
        write_files(tmp, run.disc, run.solution,
                    extra={**b.as_dict(), **run.bracket.as_dict(), "U_lower": final.U_lower, "U_upper": final.U_upper,
                           "adapt_steps": len(run.steps), "adapt_reason": run.reason, "lower_bound_kind": final.lower},
                    **gap_fields(run.disc, b))
    print(f"{run.reason}: {final.n_elements:,} elements, relative gap {final.gap_rel:.3e}"
          + ("" if math.isnan(final.U_lower) else f", U in [{final.U_lower:.6g}, {final.U_upper:.6g}]")
          + f" ({final.lower} lower bound) -> {out_dir}")
    run_b = run.bracket
    if run_b.tighter_than(final.gap_rel):
        print(f"  {run_b.line()}")
    return run.reached(options.rtol)
