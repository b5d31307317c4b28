"""The report and the figures of benchmarks/validation/axisymmetric.py, from its JSON record."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from axisymmetric import NU, cavity_pressure, hertz_mean_pressure


def pct(x: float) -> str:
    return "n/a" if x is None or not math.isfinite(x) else f"{100 * x:+.2f}%"


def g(x, d: int = 4) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, float) and not math.isfinite(x):
        return "inf" if x > 0 else "nan"
    return f"{x:.{d}g}"


def table(head: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def hertz_section(res: dict) -> str:
    h = res["hertz"]
    ref = h["reference"]
    out = [f"## 1. Hertz in the meridian plane\n\nElastic (sigma_y = 1e12), F = {h['force']:.4g} N: Hertz a = "
           f"{ref['a']:.4f} mm, p0 = {ref['p0']:.1f} MPa, delta = a^2/R = {ref['delta']:.5f} mm. Meridian square "
           "[0, L]^2, lateral face and top clamped, conic solver. `a` is the midpoint of the bracket [last active, "
           "first free contact node] (`in` says whether Hertz's a lies in it); the peak pressure is the largest "
           "nodal ring force over its consistent ring area; p_m against 2 p0 / 3.",
           f"\n### Block sizes (level {h['blocks'][0]['level']})\n"]
    rows = [[g(b["block"]), b["elements"], f"[{b['a_active']:.4f}, {b['a_free']:.4f}]", "yes" if b["a_in_bracket"]
             else "no", pct(b["a_err"]), pct(b["p_peak_err"]), pct(b["p_mean_err"]), f"{b['U_over_delta']:.4f}",
             f"{b['vm_over_p0']:.4f}", f"{b['kkt']:.0e}", b["time_s"]] for b in h["blocks"]]
    out.append(table(["L / a", "triangles", "a bracket", "in", "a - Hertz", "p_peak - p0", "p_m - 2p0/3",
                      "U / delta", "max vm / p0", "kkt", "s"], rows))
    if "extrapolated" in h:
        x = h["extrapolated"]
        out.append(f"\nExtrapolated to L -> infinity (v_inf + c / L through the two largest blocks): U / delta = "
                   f"{x['U_over_delta']:.4f}, p_peak - p0 = {pct(x['p_peak_err'])}, a - Hertz = {pct(x['a_err'])}, "
                   f"max vm / p0 = {x['vm_over_p0']:.4f} (Green's 0.6199 for nu = 0.3).")
    out.append("\n### Mesh levels (L = 20 a)\n")
    rows = [[b["level"], b["elements"], f"[{b['a_active']:.4f}, {b['a_free']:.4f}]", "yes" if b["a_in_bracket"]
             else "no", pct(b["a_err"]), pct(b["p_peak_err"]), pct(b["p_mean_err"]), f"{b['U_over_delta']:.5f}",
             f"{b['vm_over_p0']:.4f}", f"{b['kkt']:.0e}", b["time_s"]] for b in h["levels"]]
    out.append(table(["level", "triangles", "a bracket", "in", "a - Hertz", "p_peak - p0", "p_m - 2p0/3",
                      "U / delta", "max vm / p0", "kkt", "s"], rows))
    q = res.get("quarter")
    if q:
        out.append(f"\n### The same solid in 3D: a quarter cylinder (radius = height = {g(q['L'])} mm)\n\n"
                   f"gmsh quarter cylinder graded by the package's size field, symmetry planes x = 0 and y = 0, "
                   f"lateral face and top clamped, a quarter of F; newton. Reference: the meridian model of the same "
                   f"solid ({q['axi_elements']} triangles), U_axi = "
                   + ", ".join(f"{u:.6f}" for u in q["axi_U"]) + " mm at F = "
                   + ", ".join(f"{F:.4g}" for F in q["forces"]) + " N (Hertz delta "
                   + ", ".join(f"{d:.6f}" for d in q["hertz_delta"]) + ").\n")
        rows = [[g(r["h_contact"]), g(r["growth"]), r["tetrahedra"]] + [pct(d) for d in r["diff"]]
                + [f"{r['kkt']:.0e}", r["time_s"]] for r in q["rows"]]
        out.append(table(["h_contact", "growth", "tetrahedra"] + [f"U_3D / U_axi - 1 at F = {F:.4g}"
                                                                 for F in q["forces"]] + ["kkt", "s"], rows))
    return "\n".join(out)


def first_yield_section(res: dict) -> str:
    fy = res["first_yield"]
    rows = [[p["level"], p["elements"], f"{p['vm_over_p0']:.4f}", f"{p['Lambda_yield']:.4f}",
             f"{p['Lambda_yield_discrete_a']:.4f}"] for p in fy["per_level"]]
    checks = ", ".join(f"{c['plastic_elements']} plastic elements at {c['Lambda_over_yield']:g} Lambda_y"
                       for c in fy["checks"])
    return ("## 2a. First yield\n\nIn the elastic range the largest von Mises stress and a both grow as F^(1/3), so "
            "Lambda_y = E* a / (max vm R) from one elastic solve (L = 20 a) is where yield starts. Hertz with "
            f"Green's 0.6199 p0 gives Lambda_y = (pi/2) / 0.6199 = {fy['hertz_green']:.4f}.\n\n"
            + table(["level", "triangles", "max vm / p0", "Lambda_y (Hertz a)", "Lambda_y (discrete a)"], rows)
            + f"\n\nChecked with elastic-plastic solves (H/E = 1e-3) on the finest level: {checks}.")


def sweep_section(res: dict) -> str:
    rows = []
    for r in res["sweep"]["rows"]:
        rows.append([r["level"], g(r["H_over_E"]), r["elements"], f"{r['Lambda']:.3g}",
                     f"[{r['Lambda_range'][0]:.3g}, {r['Lambda_range'][1]:.3g}]", f"{r['pm_over_sy']:.3f}",
                     f"{cavity_pressure(r['Lambda']):.3f}" if r["Lambda"] > 1 else "-",
                     f"{r['p_peak'] / r['sigma_y']:.3f}", f"{r['c2']:.3f}", f"{r['pile_up_over_U']:.4f}",
                     f"{r['plastic_depth_over_a']:.2f}", f"{r['plastic_radius_over_a']:.2f}",
                     f"{r['kkt']:.0e}", r["time_s"]])
    return ("## 2b. Elastic-plastic sphere, Lambda = E* a / (sigma_y R) from 1 to 150\n\nsigma_y = E* a0 / "
            "(Lambda R) at a fixed geometry (a0 = 1 mm, R = 50 mm, block 25 mm: at least 20 a), F from a guess of "
            "p_m; Lambda is then measured from the bracket's midpoint (its two ends in the next column). newton "
            "(conic where newton did not certify). Johnson's cavity: p-bar / sigma_y = (2/3)[1 + ln (c/a)^3] (the "
            "band reaches p-bar + 2/3). Elastic p_m / sigma_y = 4 Lambda / (3 pi). pile-up / U: the largest uplift "
            "of the free surface over U; plastic zone depth and radius over a.\n\n"
            + table(["level", "H/E", "triangles", "Lambda", "Lambda bracket", "p_m/sy", "cavity p-bar/sy",
                     "p_peak/sy", "c^2", "pile-up/U", "zone depth/a", "zone radius/a", "kkt", "s"], rows))


def locking_section(res: dict) -> str:
    rows = [[r["level"], r["elements"], f"{r['Lambda']:.4g}", f"{r['pm_over_sy']:.4f}", f"{r['c2']:.4f}",
             f"{r['pile_up_over_U']:.5f}", f"{r['U_over_a2R']:.4f}", f"{r['plastic_depth_over_a']:.3f}",
             f"{r['kkt']:.0e}", r["time_s"]] for r in res["locking"]["rows"]]
    return ("## 2c. Mesh convergence in the fully plastic range (H/E = 1e-3), the locking measure\n\nEvery level "
            "halves h_contact and the growth rate (about four times the triangles). U R / a^2 = 1 / (2 c^2).\n\n"
            + table(["level", "triangles", "Lambda", "p_m/sy", "c^2", "pile-up/U", "U R/a^2", "zone depth/a",
                     "kkt", "s"], rows))


def locking_extra_section(res: dict) -> str:
    out = []
    b = res.get("beyond")
    if b:
        rows = [[r["level"], r["elements"], f"{r['Lambda']:.4g}", f"{r['pm_over_sy']:.4f}", f"{r['c2']:.4f}",
                 f"{r['pile_up_over_U']:.4f}", f"{r['plastic_depth_over_a']:.2f}", f"{r['kkt']:.0e}"]
                for r in b["rows"]]
        out.append("### Beyond the sweep (H/E = 1e-3)\n\n" + table(
            ["level", "triangles", "Lambda", "p_m/sy", "c^2", "pile-up/U", "zone depth/a", "kkt"], rows))
    inc = res.get("incompressible")
    if inc:
        rows = [[g(r["nu"]), r["level"], r["elements"], f"{r['U_over_delta']:.4f}", f"{r['p_peak_over_p0']:.4f}",
                 f"[{r['a_active']:.4f}, {r['a_free']:.4f}]", f"{r['kkt']:.0e}"] for r in inc["rows"]]
        out.append("### Volumetric locking, elastic: Hertz as nu -> 1/2 (L = 20 a)\n\nF chosen so that Hertz's a = 1 "
                   "for each nu (delta = a^2 / R = 0.02 whatever nu); U / delta against the same ratio at nu = 0.3 "
                   "(the clamped block's stiffening).\n\n" + table(
                       ["nu", "level", "triangles", "U / delta", "p_peak / p0", "a bracket", "kkt"], rows))
    pat = res.get("patterns")
    if pat:
        rows = [[r["model"], r["pattern"], r["elements"], f"{r['Lambda']:.4g}", f"{r['U']:.6f}",
                 f"{r['pm_over_sy']:.3f}", f"[{r['a_active']:.4f}, {r['a_free']:.4f}]", f"{r['c2']:.3f}",
                 f"{r['pile_up_over_U']:.4f}", f"{r['kkt']:.0e}", r["time_s"]] for r in pat["rows"]]
        out.append("### The two triangle patterns on the same nodes (H/E = 1e-3, Lambda near 100)\n\nStructured "
                   "rectangles graded toward the contact (grading 3), block 12 a (plane strain: 24 a wide), "
                   "diagonal (two triangles per cell) against crossed (four). In plane strain the crossed pattern "
                   "holds incompressible fields and the diagonal one almost none; in the meridian plane neither "
                   "does (docs/axisymmetry.md).\n\n" + table(
                       ["model", "pattern", "triangles", "Lambda", "U", "p_m/sy", "a bracket", "c^2", "pile-up/U",
                        "kkt", "s"], rows))
    return "\n\n".join(out)


def pr_section(res: dict) -> str:
    rows = [[g(r["Lambda_target"]), r["level"], r["steps"], f"{r['Lambda_hencky']:.3g}", f"{r['Lambda_pr']:.3g}",
             pct(r["U_diff"]), f"{r['pm_hencky']:.3f}", f"{r['pm_pr']:.3f}", f"{r['c2_hencky']:.3f}",
             f"{r['c2_pr']:.3f}", f"{r['pile_up_hencky']:.4f}", f"{r['pile_up_pr']:.4f}", f"{r['kkt_pr']:.0e}",
             r["time_s"]] for r in res["prandtl_reuss"]["rows"]]
    return ("## 2d. Hencky against Prandtl-Reuss on the same monotone path\n\nH/E = 1e-3; Prandtl-Reuss: n equal "
            "force steps from 0 to F (ep.solve_path, one backward-Euler step each), Hencky: one solve at F.\n\n"
            + table(["Lambda target", "level", "steps", "Lambda H", "Lambda PR", "U_PR/U_H - 1", "p_m/sy H",
                     "p_m/sy PR", "c^2 H", "c^2 PR", "pile-up/U H", "pile-up/U PR", "kkt PR", "s"], rows))


def nano_section(res: dict) -> str:
    out = ["## 3. Nanoindentation: a load-unload cycle and Oliver-Pharr\n\nH/E = 1e-3; equal force steps to F_max, "
           "then unloading to 0.02 F_max; Oliver-Pharr of `certificate/oliver_pharr.py` (fit over F >= 0.5 F_max, "
           "eps = 0.75, beta = 1). 'true' uses the contact radius at the peak (bracket midpoint): A = pi a^2.\n"]
    rows = []
    for key in ("nano_sphere", "nano_cone"):
        n = res.get(key)
        if not n or not n.get("oliver_pharr"):
            continue
        op = n["oliver_pharr"]
        shape = "sphere R = 50" if n["shape"] == "sphere" else f"cone {n['half_angle']} deg"
        rows.append([shape, n["elements"], f"{n['sigma_y']:.4g}", f"{op['F_max']:.4g}", f"{op['h_max']:.5f}",
                     f"{op['m']:.3f}" if op.get("m") else "-", f"{op['S']:.5g}", f"{op['h_c']:.5f}",
                     f"{op['hardness'] / n['sigma_y']:.3f}", f"{n['true_hardness'] / n['sigma_y']:.3f}",
                     f"{n['area_over_true']:.3f}", f"{op['E_r'] / op['E_star']:.4f}",
                     f"{n['E_r_true_area'] / op['E_star']:.4f}", f"{n['peak']['pile_up'] / op['h_max']:.4f}",
                     f"{n['kkt']:.0e}", n["time_s"]])
    out.append(table(["indenter", "triangles", "sigma_y", "F_max", "h_max", "m", "S", "h_c", "H_OP/sy",
                      "F/(pi a^2)/sy", "A_OP/A_true", "E_r/E*", "E_r(A_true)/E*", "pile-up/h_max", "kkt", "s"],
                     rows))
    for key in ("nano_sphere", "nano_cone"):
        n = res.get(key)
        if n and n.get("refused"):
            out.append(f"\n{n['shape']} (half-angle {n['half_angle']} deg, Lambda = E* tan(beta) / sigma_y = "
                       f"{g(n['Lambda'])}, {n['elements']} triangles): the Hencky solve at F_max = {n['F_max']:.4g} N "
                       f"ends `{n['status']}`: {n['refused']}")
    cone = res.get("nano_cone", {})
    if cone.get("eps_072"):
        e = cone["eps_072"]
        out.append(f"\nThe cone with eps = 0.72 (its own geometry constant): h_c = {e['h_c']:.5f}, H / sigma_y = "
                   f"{e['hardness'] / cone['sigma_y']:.3f}, E_r / E* = {e['E_r'] / cone['oliver_pharr']['E_star']:.4f}.")
    for key in ("nano_sphere", "nano_cone"):
        n = res.get(key)
        if n and "S_over_sneddon" in n:
            out.append(f"\n{n['shape']}: S / (2 E* a) = {n['S_over_sneddon']:.4f} (Sneddon's half-space stiffness "
                       "at the peak's contact radius).")
    return "\n".join(out)


def render_report(res: dict) -> str:
    parts = [f"Mode `{res['mode']}`; E = {res['E']:g} MPa, nu = {res['nu']}, R = {res['R']} mm; mesh levels "
             "(h_contact / a0, growth): " + ", ".join(f"{k} = ({g(v[0])}, {g(v[1])})" for k, v in
                                                       res["levels"].items())
             + f". Timings per section (s): {res.get('timings_s')}; total {res.get('total_time_s')} s.",
             "Figures: `axisymmetric.png` (p_m / sigma_y and c^2 against Lambda with the literature bands, the "
             "Oliver-Pharr cycle), `axisymmetric_hertz.png` (the finite-block trend and the 3D quarter model).",
             hertz_section(res), first_yield_section(res), sweep_section(res), locking_section(res),
             locking_extra_section(res), pr_section(res),
             nano_section(res)]
    return "\n\n".join(parts)


def draw(res: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.8))
    lam = np.geomspace(0.5, 300, 200)
    cav = np.array([cavity_pressure(x) for x in lam])
    ax[0].fill_between(lam, cav, cav + 2 / 3, color="0.85", label="Johnson's expanding cavity (band)")
    ax[0].plot(lam, [hertz_mean_pressure(x) for x in lam], "k:", label="Hertz 4 Lambda / (3 pi)")
    ax[0].axhspan(2.8, 3.0, xmin=0, xmax=1, color="tab:orange", alpha=0.25, label="Tabor 2.8-3.0")
    ax[0].axvline(res["first_yield"]["hertz_green"], color="0.5", lw=0.8, ls="--")
    rows = res["sweep"]["rows"]
    markers = {"L1": "s", "L2": "^", "L3": "o", "L4": "D"}
    colors = {1e-3: "tab:blue", 1e-2: "tab:red"}
    for h_ratio in sorted({r["H_over_E"] for r in rows}):
        for level in sorted({r["level"] for r in rows}):
            pts = sorted([(r["Lambda"], r["pm_over_sy"], r["c2"]) for r in rows
                          if r["level"] == level and r["H_over_E"] == h_ratio])
            if not pts:
                continue
            x, p, c = map(np.array, zip(*pts))
            kw = dict(marker=markers.get(level, "o"), color=colors.get(h_ratio, "k"), ms=4, lw=0.8,
                      label=f"H/E = {h_ratio:g}, {level}")
            ax[0].plot(x, p, **kw)
            ax[1].plot(x, c, **kw)
    ax[0].set(xscale="log", xlabel="Lambda = E* a / (sigma_y R)", ylabel="p_m / sigma_y", ylim=(0, 4),
              title="mean pressure (first yield: dashed)")
    ax[0].legend(fontsize=7, loc="upper left")
    ax[1].axhline(1.4, color="tab:orange", label="fully plastic, about 1.4 (Hill et al.)")
    ax[1].axhline(0.5, color="k", ls=":", label="Hertz 1/2")
    ax[1].set(xscale="log", xlabel="Lambda", ylabel="c^2 = a^2 / (2 R U)", title="contact depth ratio")
    ax[1].legend(fontsize=7)
    n = res.get("nano_sphere")
    if n and n.get("oliver_pharr"):
        op = n["oliver_pharr"]
        U, F = np.array(n["U"]), np.array(n["forces"])
        ax[2].plot(np.r_[0, U], np.r_[0, F], "o-", ms=3, label="path (sphere)")
        if op.get("m"):
            h = np.linspace(op["h_f"], op["h_max"], 50)
            ax[2].plot(h, op["alpha"] * (h - op["h_f"]) ** op["m"], "r--", label=f"OP fit, m = {op['m']:.2f}")
        h0 = op["h_max"] - op["F_max"] / op["S"]
        ax[2].plot([h0, op["h_max"]], [0, op["F_max"]], "g:", label="S at the peak")
        ax[2].axvline(op["h_c"], color="0.5", lw=0.8, ls="--", label="h_c")
        ax[2].set(xlabel="U (mm)", ylabel="F (N)", title=f"load-unload, H_OP/sy = {op['hardness'] / n['sigma_y']:.2f}, "
                  f"E_r/E* = {op['E_r'] / op['E_star']:.3f}")
        ax[2].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "axisymmetric.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    b = res["hertz"]["blocks"]
    L = np.array([r["block"] for r in b])
    ax[0].plot(L, [r["U_over_delta"] for r in b], "o-", label="U / delta")
    ax[0].plot(L, [1 + r["a_err"] for r in b], "s-", label="a / a_Hertz")
    ax[0].plot(L, [1 + r["p_peak_err"] for r in b], "^-", label="p_peak / p0")
    ax[0].axhline(1, color="k", lw=0.6)
    ax[0].set(xscale="log", xlabel="block L / a", title="Hertz, meridian plane: the finite block")
    ax[0].legend(fontsize=8)
    q = res.get("quarter")
    if q:
        for k, F in enumerate(q["forces"]):
            ax[1].plot([r["tetrahedra"] for r in q["rows"]], [abs(r["diff"][k]) for r in q["rows"]], "o-",
                       label=f"F = {F:.3g} N")
        ax[1].set(xscale="log", yscale="log", xlabel="tetrahedra of the quarter model",
                  ylabel="|U_3D / U_axi - 1|", title="3D quarter against the meridian model")
        ax[1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "axisymmetric_hertz.png", dpi=110)
    plt.close(fig)


__all__ = ["render_report", "draw", "NU"]
