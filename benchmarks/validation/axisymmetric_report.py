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
    cycles = list(res.get("nano_sphere_levels", [])) + [res.get("nano_sphere"), res.get("nano_cone")]
    for n in cycles:
        if not n or not n.get("oliver_pharr"):
            continue
        op = n["oliver_pharr"]
        shape = "sphere R = 50" if n["shape"] == "sphere" else f"cone {n['half_angle']} deg"
        rows.append([shape, n["level"], n["elements"], f"{n['sigma_y']:.4g}", f"{op['F_max']:.4g}", f"{op['h_max']:.5f}",
                     f"{op['m']:.3f}" if op.get("m") else "-", f"{op['S']:.5g}", f"{op['h_c']:.5f}",
                     f"{op['hardness'] / n['sigma_y']:.3f}", f"{n['true_hardness'] / n['sigma_y']:.3f}",
                     f"{n['area_over_true']:.3f}", f"{op['E_r'] / op['E_star']:.4f}",
                     f"{n['E_r_true_area'] / op['E_star']:.4f}", f"{n['peak']['pile_up'] / op['h_max']:.4f}",
                     f"{n['kkt']:.0e}", n["time_s"]])
    out.append(table(["indenter", "level", "triangles", "sigma_y", "F_max", "h_max", "m", "S", "h_c", "H_OP/sy",
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


def representative_stress(r: dict, E: float) -> float:
    """Tabor's flow stress at the representative strain 0.2 a / R of the linear hardening law
    (sigma = sigma_y + H kappa, the plastic strain kappa = 0.2 a / R - sigma_y / E), over sigma_y."""
    strain = 0.2 * r["a"] / 50.0
    return 1 + r["H_over_E"] * E * max(0.0, strain - r["sigma_y"] / E) / r["sigma_y"]


def seq(rows: list[dict], key: str, fmt: str) -> str:
    return ", ".join(format(r[key], fmt) for r in rows)


def pick(rows: list[dict], **match) -> list[dict]:
    return [r for r in rows if all(r.get(k) == v for k, v in match.items())]


def findings(res: dict) -> str:
    """The differences from the literature and their causes, with this record's numbers."""
    out = ["## What the record shows\n"]
    h = res["hertz"]
    blocks, levels = h["blocks"], h["levels"]
    x = h.get("extrapolated", {})
    inside = all(b["a_in_bracket"] for b in blocks + levels)
    out.append(
        f"- **Hertz.** Hertz's a lies in the discrete bracket on {'every' if inside else 'not every'} block and level. "
        f"The approach U / delta is {seq(blocks, 'U_over_delta', '.4f')} on blocks "
        f"{', '.join(g(b['block']) for b in blocks)} a ({x.get('U_over_delta', float('nan')):.4f} extrapolated "
        "in 1/L): the clamped finite block is stiffer than the half-space by O(a/L), the whole difference. The "
        f"peak pressure is within {max(abs(b['p_peak_err']) for b in blocks + levels[1:]) * 100:.2f}% of p0 from "
        f"level L2 on; at L = 20 a, U / delta changes by {abs(levels[-1]['U_over_delta'] - levels[-2]['U_over_delta']):.1e} "
        "between the two finest levels (mesh-converged).")
    q = res.get("quarter")
    if q and len(q["rows"]) >= 2:
        r1, r2 = q["rows"][-2], q["rows"][-1]
        rate = math.log(abs(r1["diff"][-1]) / abs(r2["diff"][-1])) / math.log(r2["tetrahedra"] / r1["tetrahedra"])
        out.append(
            f"- **3D quarter cylinder against the meridian model of the same solid.** U_3D / U_axi - 1 at the largest "
            f"force goes {', '.join(pct(r['diff'][-1]) for r in q['rows'])} over "
            f"{', '.join(str(r['tetrahedra']) for r in q['rows'])} tetrahedra (about N^-{rate:.2f} between the two "
            "finest, h^" f"{3 * rate:.1f}" "); the same trend at every force, so F against U converges to the "
            "axisymmetric curve. The 3D model is the stiffer one: P1 tetrahedra on a coarser resolution of the "
            "contact (its h_contact is 8 to 30 times the meridian mesh's).")
    fy = res["first_yield"]
    last = fy["per_level"][-1]
    out.append(
        f"- **First yield** at Lambda_y = {last['Lambda_yield']:.4f} on the finest level ({pct(last['Lambda_yield'] / fy['hertz_green'] - 1)} "
        f"against Hertz with Green's 0.6199, {pct(last['Lambda_yield'] / (math.pi / 2 * 1.60) - 1)} against Johnson's "
        f"p0 = 1.60 sigma_y): max vm / p0 = {last['vm_over_p0']:.4f} (Green 0.6199, Johnson 1 / 1.60 = 0.625); the "
        "element-mean (P0) stress and the clamped block move it by well under 1%.")
    rows = res["sweep"]["rows"]
    finest = max({r["level"] for r in rows})
    parts = []
    for hr in sorted({r["H_over_E"] for r in rows}):
        for r in sorted(pick(rows, level=finest, H_over_E=hr), key=lambda r: r["Lambda"]):
            if r["Lambda"] >= 25:
                parts.append(f"H/E = {hr:g}, Lambda = {r['Lambda']:.3g}: p_m / sigma_y = {r['pm_over_sy']:.3f} "
                             f"(bracket {r['p_mean_range'][0] / r['sigma_y']:.3f} to {r['p_mean_range'][1] / r['sigma_y']:.3f}), "
                             f"over Tabor's flow stress at 0.2 a / R: {r['pm_over_sy'] / representative_stress(r, res['E']):.3f}")
    band = {"below": [], "inside": [], "above": []}
    for r in sorted(pick(rows, level=finest, H_over_E=1e-3), key=lambda r: r["Lambda"]):
        if r["Lambda"] < 2.5:
            continue
        lo = cavity_pressure(r["Lambda"])
        where = "below" if r["pm_over_sy"] < lo else "inside" if r["pm_over_sy"] <= lo + 2 / 3 else "above"
        band[where].append(f"{r['Lambda']:.3g}")
    placed = "; ".join(f"{k} at Lambda = {', '.join(v)}" for k, v in band.items() if v)
    out.append(
        f"- **Mean pressure** (level {finest}). Below Lambda = 2.5 p_m follows Hertz's 4 Lambda / (3 pi). Against "
        f"Johnson's expanding-cavity band [p-bar, p-bar + 2/3] (H/E = 1e-3): {placed}. The cavity model is a "
        "cone's, with the sphere entering through tan(beta) = a / R; it lags in the elastic-plastic transition, "
        "where the computed p_m rises faster, and overshoots it once p_m levels off (its p-bar keeps growing as "
        "ln Lambda). In the fully plastic range: " + "; ".join(parts) + ". With H/E = 1e-3 p_m is 2.5 to 2.7 at "
        "Lambda 30 to 50 and reaches Tabor's 2.8 to 3.0 from Lambda about 100; with H/E = 1e-2 it exceeds 3 because the flow stress at Tabor's representative strain 0.2 a / R is "
        "well above sigma_y at large Lambda (sigma_y / E falls as 1 / Lambda while H / E is fixed): divided by that "
        "flow stress it is back near 2.8 to 2.9.")
    lk = res["locking"]["rows"]
    for lam in sorted({r["Lambda_target"] for r in lk}):
        rr = pick(lk, Lambda_target=lam)
        out.append(
            f"- **Mesh convergence at Lambda about {g(lam)}** ({', '.join(str(r['elements']) for r in rr)} triangles): "
            f"p_m / sigma_y {seq(rr, 'pm_over_sy', '.3f')}; c^2 "
            f"{seq(rr, 'c2', '.3f')}; pile-up / U {seq(rr, 'pile_up_over_U', '.4f')}; "
            f"U R / a^2 {seq(rr, 'U_over_a2R', '.4f')}. The p_m steps are mostly the contact "
            "bracket's resolution (a node spacing of a / 20 to a / 160 moves p_m by up to 2 h / a).")
    be = res.get("beyond", {}).get("rows", [])
    c2_parts = ", ".join(f"{r['c2']:.3f} at Lambda = {r['Lambda']:.3g} ({r['level']}, p_m / sigma_y = "
                         f"{r['pm_over_sy']:.2f})" for r in be)
    top = sorted(pick(rows, level=finest, H_over_E=1e-3), key=lambda r: r["Lambda"])
    near100 = min(top, key=lambda r: abs(math.log(r["Lambda"] / 100)))
    settled = bool(be) and max(r["c2"] for r in be) - near100["c2"] < 0.05
    out.append(
        "- **c^2 = a^2 / (2 R U) stays near 1, not 1.4.** It rises from Hertz's 1/2 to "
        f"{near100['c2']:.3f} at Lambda = {near100['Lambda']:.3g} and {top[-1]['c2']:.3f} at "
        f"{top[-1]['Lambda']:.3g} (H/E = 1e-3, {finest}); beyond the sweep: {c2_parts}. The literature's 1.4 is the "
        "fully plastic (similarity) value with pile-up for small hardening. "
        + ("The figure has levelled off, so a larger Lambda is not what is missing (at Lambda 300 to 1000, with H/E "
           "fixed, the hardening is no longer small against sigma_y: p_m climbs above 3 and hardening lowers "
           "c^2). " if settled else "The figure still rises with Lambda, so part of the difference is that the "
           "fully plastic limit is not reached. ")
        + "This record does not establish the cause. The first suspect is volumetric locking of the P1 triangles "
        "in the meridian plane (measured below): it resists the incompressible plastic flow that raises material "
        "beside the indenter, and pile-up widens the contact (a larger a, a larger c^2); refining these meshes does "
        "not remove it (the table of 2c: c^2 and pile-up move by a few per cent over a 50-fold increase in "
        "triangles).")
    inc = res.get("incompressible", {}).get("rows", [])
    if inc:
        n3 = pick(inc, nu=0.3)
        nmax = max(r["nu"] for r in inc)
        ni = pick(inc, nu=nmax)
        out.append(
            f"- **Locking, elastic measure.** For elastic Hertz with nu = {nmax} the approach U / delta is "
            f"{seq(ni, 'U_over_delta', '.4f')} on levels {', '.join(r['level'] for r in ni)}, "
            f"against {seq(n3, 'U_over_delta', '.4f')} at nu = 0.3 (same blocks), and the peak "
            f"pressure oscillates ({seq(ni, 'p_peak_over_p0', '.2f')} p0): the element is too stiff "
            "for nearly incompressible deformation and the error falls only slowly under refinement.")
    pat = res.get("patterns", {}).get("rows", [])
    if pat:
        def row(model, pattern):
            return next(r for r in pat if r["model"] == model and r["pattern"] == pattern)
        ps_d, ps_c = row("plane-strain cylinder", "diagonal"), row("plane-strain cylinder", "crossed")
        ax_d, ax_c = row("axisymmetric sphere", "diagonal"), row("axisymmetric sphere", "crossed")
        graded = max(pick(res["locking"]["rows"], Lambda_target=100.0) or [{}], key=lambda r: r.get("elements", 0))
        graded_text = (f" The graded meshes of the sweep sit with the crossed pattern (level {graded['level']} at Lambda "
                       f"{graded['Lambda']:.3g}: c^2 {graded['c2']:.3f}, pile-up / U {graded['pile_up_over_U']:.4f})."
                       if graded else "")
        spacing = max(r["a_free"] - r["a_active"] for r in pat)
        out.append(
            "- **Locking, plastic measure (the same nodes, two triangle patterns, Lambda about 100).** Plane strain, "
            f"where the crossed pattern does not lock: going from diagonal to crossed U {pct(ps_c['U'] / ps_d['U'] - 1)} "
            f"and pile-up / U {ps_d['pile_up_over_U']:.4f} -> {ps_c['pile_up_over_U']:.4f}. Meridian plane (neither "
            f"pattern is free of locking): U {pct(ax_c['U'] / ax_d['U'] - 1)}, pile-up / U {ax_d['pile_up_over_U']:.4f} "
            f"-> {ax_c['pile_up_over_U']:.4f}. These two are resolved; p_m and c^2 are not: the contact node spacing "
            f"of these structured meshes is up to {spacing:.3f} a, and the bracket's midpoint moved by one node between "
            f"the patterns (meridian plane: c^2 {ax_d['c2']:.3f} -> {ax_c['c2']:.3f}, p_m / sigma_y "
            f"{ax_d['pm_over_sy']:.3f} -> {ax_c['pm_over_sy']:.3f}, mostly that step)." + graded_text + " So the "
            "locking that can be switched off moves the fully plastic U by about 4% and the pile-up by a factor 1.5 "
            "to 2 (the locking mesh is the stiffer, with less pile-up); what the crossed and graded meridian meshes "
            "still hold back is not measured here (no locking-free axisymmetric element yet: a separate issue).")
    pr = res["prandtl_reuss"]["rows"]
    out.append(
        "- **Hencky against Prandtl-Reuss** (same monotone force path): U_PR / U_H - 1 = "
        + "; ".join(f"{pct(r['U_diff'])} at Lambda {r['Lambda_hencky']:.3g} ({r['level']}, {r['steps']} steps)"
                    for r in pr)
        + ". Prandtl-Reuss is the stiffer: the stress path of an element under a spreading contact is not "
        "proportional (the principal axes turn as the contact edge passes), and Hencky's deformation law answers a "
        "turning strain with the secant modulus where the flow law answers elastically. The difference grows with "
        "the number of steps (the backward-Euler path is not converged in its steps at 10 or 20).")
    n = res.get("nano_sphere")
    if n and n.get("oliver_pharr"):
        op = n["oliver_pharr"]
        others = [m for m in res.get("nano_sphere_levels", []) if m.get("oliver_pharr")]
        conv = ("; on the coarser levels " + ", ".join(
            f"{m['level']}: E_r / E* {m['oliver_pharr']['E_r'] / m['oliver_pharr']['E_star']:.4f}, H_OP / sigma_y "
            f"{m['oliver_pharr']['hardness'] / m['sigma_y']:.3f}, A_OP / pi a^2 {m['area_over_true']:.3f}"
            for m in others) + "") if others else ""
        out.append(
            f"- **Oliver-Pharr (sphere, Lambda about {g(n['Lambda'])}, level {n['level']}{conv}).** E_r / E* = "
            f"{op['E_r'] / op['E_star']:.4f}, "
            f"H_OP = {op['hardness'] / n['sigma_y']:.3f} sigma_y against F / (pi a^2) = "
            f"{n['true_hardness'] / n['sigma_y']:.3f} sigma_y at the peak. Two biases, each measured: the projected "
            f"area from h_c with eps = 0.75 is {n['area_over_true']:.3f} of the true pi a^2 (eps = 0.75 assumes "
            "Hertz's elastic sink-in, c^2 = 1/2; here the surface sinks in less, c^2 about 0.9, so h_c and the area "
            "come out too small, H and E_r too large), and the unloading stiffness is "
            f"{n['S_over_sneddon']:.4f} times Sneddon's 2 E* a (the clamped block, as in Hertz's U / delta); with the "
            f"true area E_r / E* = {n['E_r_true_area'] / op['E_star']:.4f}. The fit (m = {op['m']:.3f} over "
            f"{op['n_fit']} points with F >= 0.5 F_max, largest residual {op['fit_residual']:.1e}) is the finite "
            "unloading fit: S is the fitted law's slope at the peak, not the limit of a continuous curve. Pile-up at "
            f"the peak: {n['peak']['pile_up'] / op['h_max']:.4f} h_max (the sweep shows pile-up from Lambda about 50 "
            "and locking lowers it, above), so the pile-up bias of real tests "
            "(material raised against the indenter: the true area above Oliver-Pharr's, so H and E_r come out too "
            "large by more) is absent here.")
    c = res.get("nano_cone")
    if c and c.get("refused"):
        out.append(
            f"- **The 70.3 deg cone** (Berkovich-equivalent) is not recorded: its Hencky solve at F_max is refused by "
            "the small-strain check (strains above 0.1 at the tip; the message is in section 3). A sharp cone's "
            "tip is a finite-strain problem; this model does not cover it.")
    return "\n".join(out)


def render_report(res: dict) -> str:
    parts = [f"Mode `{res['mode']}`; E = {res['E']:g} MPa, nu = {res['nu']}, R = {res['R']} mm; mesh levels "
             "(h_contact / a0, growth): " + ", ".join(f"{k} = ({g(v[0])}, {g(v[1])})" for k, v in
                                                       res["levels"].items())
             + f". Timings per section (s): {res.get('timings_s')}; total {res.get('total_time_s')} s.",
             "Figures: `axisymmetric.png` (p_m / sigma_y and c^2 against Lambda with the literature bands, the "
             "Oliver-Pharr cycle), `axisymmetric_hertz.png` (the finite-block trend and the 3D quarter model).",
             findings(res), hertz_section(res), first_yield_section(res), sweep_section(res), locking_section(res),
             locking_extra_section(res), pr_section(res),
             nano_section(res)]
    return "\n\n".join(parts)


def draw(res: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.8))
    lam = np.geomspace(2.5, 300, 200)  # the cavity model from first yield on
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
    ax[0].legend(fontsize=7, loc="lower right")
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
    for axis in ax:
        axis.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    fig.tight_layout()
    fig.savefig(out / "axisymmetric_hertz.png", dpi=110)
    plt.close(fig)


__all__ = ["render_report", "draw", "NU"]
