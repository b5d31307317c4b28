"""Uzawa (docs/methods.md) against the conic reference (Clarabel) -- issue 3.

Every run is its own subprocess, so its peak memory (VmHWM of that process:
imports, discretisation and solve) is its own. Each run stores its
answer; the errors of Uzawa are measured against the conic run of the same case.

Sections:

* ``sizes``: 2D cylinder and 3D sphere-on-block families across mesh sizes;
* ``rho``: a sweep of the step as a share of the bound 2 / lambda_max(C);
* ``hardening``: a sweep of H = E/10, E/100, E/1000 (Uzawa and conic).

Usage::

    python benchmarks/uzawa/run.py            # full run: results.json, REPORT.md, *.png in this folder
    python benchmarks/uzawa/run.py --quick    # small cases, into quick/ (not committed)
    python benchmarks/uzawa/run.py --report   # only REPORT.md and the plots again, from results.json

The side studies ``components.py`` (factorisation of G, contact QP) and
``weight.py`` (the weight of V in the metric) write their own records.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import peak_memory, run_child, run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

E = 200000.0
SIZES = {
    "cylinder_2d": [[40, 20], [80, 40], [160, 80]],
    "sphere_block_3d": [[10, 10, 5], [16, 16, 8], [20, 20, 10], [26, 26, 13]],
}
RHO_SHARES = [0.5, 0.7, 0.85, 0.95, 0.99]
RHO_CASES = [("cylinder_2d", [80, 40]), ("sphere_block_3d", [16, 16, 8])]
HARDENING = [E / 10, E / 100, E / 1000]
H_CASES = [("cylinder_2d", [80, 40]), ("sphere_block_3d", [16, 16, 8])]
QUICK = {
    "sizes": {"cylinder_2d": [[40, 20], [80, 40]], "sphere_block_3d": [[8, 8, 4], [10, 10, 5]]},
    "rho": [("cylinder_2d", [40, 20])],
    "hardening": [("sphere_block_3d", [8, 8, 4])],
}
TOL = 1e-6


# ----------------------------------------------------------------------------
# one run, in a child process
# ----------------------------------------------------------------------------


def child(spec: dict) -> dict:
    """Discretise, solve by one method, store the answer; returns the measured row."""
    import elastoplast as ep
    from common import family

    disc = family(spec["problem"], spec["divisions"], **spec.get("material", {}))
    t0 = time.perf_counter()
    sol = ep.solve(disc, spec["method"], **spec.get("options", {}))
    wall = time.perf_counter() - t0
    np.savez(spec["store"], sigma=sol.sigma, xi=sol.xi, U=sol.U, active=sol.active, plastic=sol.plastic)
    return {
        "status": sol.status.value, "iterations": sol.iterations, "time_s": wall, "timings": sol.timings,
        "message": sol.message,
        "kkt": sol.kkt.as_dict(), "kkt_worst": sol.kkt.worst, "duality_gap": sol.duality_gap, "U": sol.U,
        "n_elements": disc.n_elements, "n_free": disc.n_free, "n_contact": disc.n_contact,
        "n_plastic": int(sol.plastic.sum()), "n_active": int(sol.active.sum()),
        "peak_rss_mb": peak_memory() / 2**20,
    }


def spawn(spec: dict) -> dict:
    """:func:`child` in its own process: the measured row, or the spec marked crashed."""
    row = {**spec, **run_child(__file__, spec)}
    if "error" in row:
        return {**row, "status": "crashed"}
    print(f"  {spec['problem']} {spec['divisions']} {spec['method']} {spec.get('material', {})} "
          f"{spec.get('options', {})}: {row['status']}, {row['iterations']} it, {row['time_s']:.2f} s, "
          f"KKT {row['kkt_worst']:.1e}, {row['peak_rss_mb']:.0f} MB", flush=True)
    return row


def errors(uz: dict, ref: dict) -> dict:
    """Uzawa's distance to the conic answer of the same case."""
    from common import family

    from elastoplast.certificate.kkt import energy_norm_sq

    if "crashed" in (uz["status"], ref["status"]):
        return {}
    disc = family(uz["problem"], uz["divisions"], **uz.get("material", {}))
    a, b = np.load(uz["store"]), np.load(ref["store"])
    num = energy_norm_sq(disc, a["sigma"] - b["sigma"], a["xi"] - b["xi"])
    return {
        "error_U": float(abs(a["U"] - b["U"]) / abs(b["U"])),
        "error_stress_energy": float(np.sqrt(num / energy_norm_sq(disc, b["sigma"], b["xi"]))),
        "active_differ": int(np.sum(a["active"] != b["active"])),
        "plastic_differ": int(np.sum(a["plastic"] != b["plastic"])),
    }


def pair(store: Path, problem: str, divisions: list[int], material: dict | None = None,
         uzawa_options: dict | None = None) -> tuple[dict, dict]:
    tag = f"{problem}_{'x'.join(map(str, divisions))}_{'_'.join(f'{k}{v:g}' for k, v in (material or {}).items())}"
    base = {"problem": problem, "divisions": divisions, "material": material or {}}
    ref = spawn({**base, "method": "conic", "store": str(store / f"{tag}_conic.npz")})
    uz = spawn({**base, "method": "uzawa", "options": {"tol": TOL, **(uzawa_options or {})},
              "store": str(store / f"{tag}_uzawa.npz")})
    uz.update(errors(uz, ref))
    return ref, uz


# ----------------------------------------------------------------------------
# sections
# ----------------------------------------------------------------------------


def section_sizes(store: Path, sizes: dict) -> list[dict]:
    rows = []
    for problem, divs in sizes.items():
        for div in divs:
            ref, uz = pair(store, problem, div)
            rows += [ref, uz]
    return rows


def section_rho(store: Path, cases) -> list[dict]:
    from elastoplast.solvers.uzawa import rho_bound
    from common import family

    rows = []
    for problem, div in cases:
        bound = rho_bound(family(problem, div).material)
        for share in RHO_SHARES:
            row = spawn({"problem": problem, "divisions": div, "method": "uzawa",
                       "options": {"tol": TOL, "rho": share * bound, "max_iter": 20000},
                       "store": str(store / f"rho_{problem}_{share}.npz")})
            rows.append({**row, "rho_share": share})
    return rows


def section_hardening(store: Path, cases) -> list[dict]:
    rows = []
    for problem, div in cases:
        for H in HARDENING:
            ref, uz = pair(store, problem, div, {"hardening": H}, {"max_iter": 20000})
            rows += [{**ref, "H": H}, {**uz, "H": H}]
    return rows


# ----------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------


def _fmt(v, spec=".3g"):
    return "-" if v is None else format(v, spec)


TITLE = "Uzawa against the conic reference"


def markdown(results: dict) -> str:
    """The report's body: the tables of ``results`` (discussion: README.md)."""
    meta = results["meta"]
    # records from before the stamp carried their own command, date and machine
    legacy = (f"Run as `{meta['command']}` on {meta['date']} ({meta['machine']}). "
              if "command" in meta and "stamp" not in results else "")
    out = [legacy + f"Uzawa stops at every KKT residual <= {meta['tol']:g}, the conic reference runs at its default tolerance. "
           "Times are wall-clock seconds of the solve (factorisation and setup included, discretisation not); "
           "memory is the peak RSS of the process that ran the case. Errors are Uzawa's distance to the conic "
           "answer: U relative, stresses in the energy norm, and the number of contact nodes / elements whose "
           "active / plastic flag differs.", ""]
    big = [(ref, uz) for ref, uz in zip(results["sizes"][::2], results["sizes"][1::2])
           if ref["problem"] == "sphere_block_3d" and uz.get("n_elements", 0) >= 50000 and "time_s" in ref and "time_s" in uz]
    for ref, uz in big:
        out += [f"**Key ratio** (issue 3 target: >= 5): 3D sphere, {uz['n_elements']} tetrahedra: conic "
                f"{ref['time_s']:.1f} s (KKT {ref['kkt_worst']:.1e}), Uzawa {uz['time_s']:.1f} s (KKT {uz['kkt_worst']:.1e}, "
                f"{uz['iterations']} iterations): conic / Uzawa = **{ref['time_s'] / uz['time_s']:.1f}**."
                + (f" Uzawa's path: {uz['message']}." if uz.get("message") else ""), ""]
    out += ["## Sizes", "",
            "| problem | elements | contact nodes | conic s | conic it | conic KKT | conic MB | Uzawa s | Uzawa it "
            "| Uzawa KKT | Uzawa MB | conic/Uzawa time | err U | err stress | active diff | plastic diff | plastic el. |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rows = results["sizes"]
    for ref, uz in zip(rows[::2], rows[1::2]):
        ratio = ref["time_s"] / uz["time_s"] if "time_s" in ref and "time_s" in uz else None
        out.append(f"| {ref['problem']} | {uz.get('n_elements')} | {uz.get('n_contact')} | {_fmt(ref.get('time_s'))} "
                   f"| {ref.get('iterations')} | {_fmt(ref.get('kkt_worst'), '.1e')} | {_fmt(ref.get('peak_rss_mb'), '.0f')} "
                   f"| {_fmt(uz.get('time_s'))} | {uz.get('iterations')} | {_fmt(uz.get('kkt_worst'), '.1e')} "
                   f"| {_fmt(uz.get('peak_rss_mb'), '.0f')} | {_fmt(ratio, '.2f')} | {_fmt(uz.get('error_U'), '.1e')} "
                   f"| {_fmt(uz.get('error_stress_energy'), '.1e')} | {uz.get('active_differ')} | {uz.get('plastic_differ')} "
                   f"| {ref.get('n_plastic')} |")
    out += ["", "## Step rho (Uzawa only)", "", "| problem | elements | rho / bound | iterations | s | KKT |", "|---|---|---|---|---|---|"]
    for r in results["rho"]:
        out.append(f"| {r['problem']} | {r.get('n_elements')} | {r['rho_share']} | {r.get('iterations')} "
                   f"| {_fmt(r.get('time_s'))} | {_fmt(r.get('kkt_worst'), '.1e')} |")
    out += ["", "## Hardening H", "",
            "| problem | elements | H / E | conic s | conic KKT | Uzawa s | Uzawa it | Uzawa KKT | err U | err stress | plastic el. | plastic diff |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rows = results["hardening"]
    for ref, uz in zip(rows[::2], rows[1::2]):
        out.append(f"| {ref['problem']} | {uz.get('n_elements')} | {ref['H'] / E:g} | {_fmt(ref.get('time_s'))} "
                   f"| {_fmt(ref.get('kkt_worst'), '.1e')} | {_fmt(uz.get('time_s'))} | {uz.get('iterations')} "
                   f"| {_fmt(uz.get('kkt_worst'), '.1e')} | {_fmt(uz.get('error_U'), '.1e')} "
                   f"| {_fmt(uz.get('error_stress_energy'), '.1e')} | {ref.get('n_plastic')} | {uz.get('plastic_differ')} |")
    return "\n".join(out) + "\n"


def plots(results: dict, out_dir: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 4), layout="constrained")
    ax_t, ax_i = fig.subplots(1, 2)
    rows = results["sizes"]
    for problem in dict.fromkeys(r["problem"] for r in rows):
        for method, style in (("conic", "s--"), ("uzawa", "o-")):
            sel = [r for r in rows if r["problem"] == problem and r["method"] == method and "time_s" in r]
            n = [r["n_elements"] for r in sel]
            ax_t.loglog(n, [r["time_s"] for r in sel], style, label=f"{problem} {method}")
            ax_i.semilogx(n, [r["iterations"] for r in sel], style, label=f"{problem} {method}")
    ax_t.set(xlabel="elements", ylabel="solve time [s]", title="time")
    ax_i.set(xlabel="elements", ylabel="iterations", title="iterations")
    for ax in (ax_t, ax_i):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.savefig(out_dir / "sizes.png", dpi=110)

    fig = Figure(figsize=(5, 4), layout="constrained")
    ax = fig.subplots()
    for problem in dict.fromkeys(r["problem"] for r in results["rho"]):
        sel = [r for r in results["rho"] if r["problem"] == problem]
        ax.plot([r["rho_share"] for r in sel], [r.get("iterations") for r in sel], "o-", label=problem)
    ax.set(xlabel="rho / (2 / lambda_max(C))", ylabel=f"iterations to KKT <= {TOL:g}", title="step sweep")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7)
    fig.savefig(out_dir / "rho.png", dpi=110)

    fig = Figure(figsize=(5, 4), layout="constrained")
    ax = fig.subplots()
    rows = results["hardening"]
    for problem in dict.fromkeys(r["problem"] for r in rows):
        sel = [r for r in rows if r["problem"] == problem and r["method"] == "uzawa"]
        ax.semilogx([r["H"] / E for r in sel], [r.get("iterations") for r in sel], "o-", label=problem)
    ax.set(xlabel="H / E", ylabel=f"Uzawa iterations to KKT <= {TOL:g}", title="hardening sweep")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    fig.savefig(out_dir / "hardening.png", dpi=110)


def measure(mode: str, out: Path) -> dict:
    """The three sections, every run in its own process."""
    quick = mode == "quick"
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        store = Path(tmp)
        results = {"meta": {"quick": quick, "tol": TOL}}
        print("sizes", flush=True)
        results["sizes"] = section_sizes(store, QUICK["sizes"] if quick else SIZES)
        print("rho", flush=True)
        results["rho"] = section_rho(store, QUICK["rho"] if quick else RHO_CASES)
        print("hardening", flush=True)
        results["hardening"] = section_hardening(store, QUICK["hardening"] if quick else H_CASES)
    results["meta"]["total_s"] = time.perf_counter() - t0
    for section in ("sizes", "rho", "hardening"):
        for row in results[section]:
            row.pop("store", None)  # temporary files, gone
    return results


def main(argv=None) -> int:
    return run_record(__doc__, "small cases", HERE, TITLE, "Uzawa benchmark", measure, markdown, plots, argv=argv,
                      child=child)


if __name__ == "__main__":
    sys.exit(main())
