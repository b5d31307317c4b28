"""Validation study of issue 5: run every comparison, write results.json, REPORT.md and plots.

    python benchmarks/validation/run.py            # full study (180 s wall in the recorded run, 2 cores)
    python benchmarks/validation/run.py --quick    # small meshes (10 s wall)
    python benchmarks/validation/run.py --report   # only REPORT.md and the plots again, from results.json

The full study writes into this folder (committed); ``--quick`` writes into
``quick/`` below it unless ``--out`` says otherwise.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import references as ref  # noqa: E402
import study  # noqa: E402

#: mesh sizes of the two modes; every comparison reads its own entry
SIZES = {
    "full": {
        "cyl_mesh_nh": [23, 45, 90], "cyl_block_L": [5.0, 10.0, 20.0, 40.0], "cyl_block_h": 0.1,
        "sph_mesh_n": [8, 12, 16, 24], "sph_block_L": [4.0, 8.0, 16.0], "sph_block_n": [10, 16, 25],
        "yield_cyl": (20.0, 90), "yield_sph": (8.0, 16),
        "conv_nh": [8, 16, 32, 64, 128],
        "load_nh": 48, "load_points": 16,
        "punch_nh": [4, 8, 16, 32, 64], "punch_H_nh": 16,
    },
    "quick": {
        "cyl_mesh_nh": [12, 23], "cyl_block_L": [5.0, 10.0], "cyl_block_h": 0.2,
        "sph_mesh_n": [6, 8], "sph_block_L": [4.0, 8.0], "sph_block_n": [6, 10],
        "yield_cyl": (10.0, 32), "yield_sph": (6.0, 8),
        "conv_nh": [8, 16, 32],
        "load_nh": 16, "load_points": 6,
        "punch_nh": [4, 8, 16], "punch_H_nh": 8,
    },
}


def run_all(mode: str) -> dict:
    s = SIZES[mode]
    out: dict = {"mode": mode, "elastic_method_3d": study.elastic_method(3)}
    timings = {}

    def timed(name, fn):
        t0 = time.perf_counter()
        out[name] = fn()
        timings[name] = round(time.perf_counter() - t0, 1)
        print(f"  {name}: {timings[name]} s", flush=True)

    timed("hertz_cylinder", lambda: study.hertz_cylinder_study(s["cyl_mesh_nh"], s["cyl_block_L"], block_h=s["cyl_block_h"]))
    timed("hertz_sphere", lambda: study.hertz_sphere_study(s["sph_mesh_n"], s["sph_block_L"], s["sph_block_n"]))
    timed("first_yield_cylinder", lambda: study.first_yield_cylinder(*s["yield_cyl"]))
    timed("first_yield_sphere", lambda: study.first_yield_sphere(*s["yield_sph"]))
    timed("convergence", lambda: study.convergence_study(s["conv_nh"]))
    F_y = out["first_yield_cylinder"]["reference"]["F_yield"]
    forces = list(F_y * np.geomspace(0.1, 8.0, s["load_points"]))
    timed("load_displacement", lambda: study.load_displacement(forces, nh=s["load_nh"]))
    timed("punch", lambda: study.punch_study(s["punch_nh"], h_nh=s["punch_H_nh"]))
    out["timings_s"] = timings
    return out


# ----------------------------------------------------------------------------
# plots
# ----------------------------------------------------------------------------


def plots(res: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def save(fig, name):
        fig.tight_layout()
        fig.savefig(out / name, dpi=110)
        plt.close(fig)

    # Hertz: differences against h and against block size
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    c, sp_ = res["hertz_cylinder"], res["hertz_sphere"]
    for rows, hkey, keys, tag in ((c["mesh_sequence"], "h_at_b_over_b", ("b_err", "p0_err"), "2D"),
                                  (sp_["mesh_sequence"], "h_at_a_over_a", ("a_err", "p0_err", "U_over_delta"), "3D")):
        h = [r[hkey] for r in rows]
        for k in keys:
            val = [abs(r[k] - (1.0 if k == "U_over_delta" else 0.0)) for r in rows]
            ax[0].loglog(h, val, "o-", label=f"{tag} |{k.replace('_over_delta', '/delta - 1')}|")
    ax[0].set_xlabel("contact-node spacing at the contact edge / contact size")
    ax[0].set_ylabel("relative difference to Hertz")
    ax[0].set_title("Hertz: mesh sequence")
    ax[0].legend(fontsize=7)
    for rows, Lkey, keys, tag in ((c["block_sizes"], "L_over_b", ("vm_over_p0", "p0_err"), "2D"),
                                  (sp_["block_sizes"], "L_over_a", ("vm_over_p0", "U_over_delta", "p0_err"), "3D")):
        L = [r[Lkey] for r in rows]
        for k in keys:
            ax[1].plot(L, [r[k] for r in rows], "o-", label=f"{tag} {k}")
    ax[1].axhline(c["reference"]["green_vm_over_p0"], ls=":", c="k", lw=0.8)
    ax[1].axhline(sp_["reference"]["green_vm_over_p0"], ls="--", c="k", lw=0.8)
    ax[1].set_xscale("log")
    ax[1].set_xlabel("block half-width / contact size")
    ax[1].set_title("finite block (dotted/dashed: Green vm/p0, 2D/3D)")
    ax[1].legend(fontsize=7)
    save(fig, "hertz.png")

    # convergence
    conv = res["convergence"]
    fig, ax = plt.subplots(figsize=(5.5, 4))
    h = np.array([r["h_rel"] for r in conv["levels"]])
    for k, lab in (("e_sigma_energy", "stress, energy norm"), ("e_strain_L2", "strain of u, L2"),
                   ("e_u_max", "u, max at nodes"), ("e_U", "U")):
        ax.loglog(h, [r[k] for r in conv["levels"]], "o-", label=f"{lab} (rate {conv['rates'][k]:.2f})")
    e0 = conv["levels"][-1]["e_sigma_energy"]
    ax.loglog(h, e0 * (h / h[-1]) ** 0.5, "k:", label="h^1/2 (Theorem 2)")
    ax.set_xlabel("h / h_finest")
    ax.set_ylabel("relative error against the finest mesh")
    ax.legend(fontsize=7)
    save(fig, "convergence.png")

    # load-displacement
    ld = res["load_displacement"]
    F = np.array([p["F"] for p in ld["points"]])
    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    ax[0].plot(F, [p["plastic"]["U"] for p in ld["points"]], "o-", label="elasto-plastic")
    ax[0].plot(F, [p["elastic"]["U"] for p in ld["points"]], "s--", label="elastic")
    ax[0].set_xlabel("F (N/mm)")
    ax[0].set_ylabel("U (mm)")
    ax[0].legend()
    ax[1].plot(F, [p["plastic"]["contact_radius"] for p in ld["points"]], "o-", label="contact half-width, plastic")
    ax[1].plot(F, [p["elastic"]["contact_radius"] for p in ld["points"]], "s--", label="contact half-width, elastic")
    ax[1].plot(F, [p["hertz_b"] for p in ld["points"]], "k:", label="Hertz b")
    ax[1].plot(F, [p["plastic"]["zone"]["depth"] for p in ld["points"]], "^-", label="plastic zone depth")
    ax[1].plot(F, [p["plastic"]["zone"]["half_width"] for p in ld["points"]], "v-", label="plastic zone half-width")
    ax[1].set_xlabel("F (N/mm)")
    ax[1].set_ylabel("mm")
    ax[1].legend(fontsize=7)
    ax[2].plot(F, [p["plastic"]["max_contact_pressure"] for p in ld["points"]], "o-", label="peak pressure, plastic")
    ax[2].plot(F, [p["elastic"]["max_contact_pressure"] for p in ld["points"]], "s--", label="peak pressure, elastic")
    ax[2].plot(F, [ref.hertz_cylinder(f, study.R, study.E, study.NU)["p0"] for f in F], "k:", label="Hertz p0")
    ax[2].set_xlabel("F (N/mm)")
    ax[2].set_ylabel("MPa")
    ax[2].legend(fontsize=7)
    save(fig, "load_displacement.png")

    # punch
    pu = res["punch"]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].plot([r["h_over_w"] for r in pu["mesh_sequence"]], [r["p_over_prandtl"] for r in pu["mesh_sequence"]], "o-")
    ax[0].axhline(1.0, c="k", ls=":")
    ax[0].set_xlabel("h / w")
    ax[0].set_ylabel("discrete limit pressure / Prandtl (2+pi)k")
    ax[0].set_xlim(left=0)
    for s in pu["H_to_zero"]["series"]:
        Hs = [r["H_over_E"] for r in s["hardening_sweep"]]
        ax[1].loglog(Hs, [r["U"] for r in s["hardening_sweep"]], "o-", label=f"U, F = {s['F_over_limit']} F_lim")
        if s["H0_U"] is not None:
            ax[1].axhline(s["H0_U"], ls=":", c="k", lw=0.8)
    ax[1].set_xlabel("H / E")
    ax[1].set_ylabel("U (mm)")
    ax[1].legend(fontsize=7)
    save(fig, "punch.png")


# ----------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------


def pct(x: float) -> str:
    return f"{100 * x:+.2f}%"


def table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


#: the figures :func:`plots` draws, in the order the report shows them
FIGURES = ["hertz.png", "convergence.png", "load_displacement.png", "punch.png"]
TITLE = "Validation against outside references"


def report(res: dict) -> str:
    """The report's body: every comparison's tables (discussion: README.md)."""
    c, s3 = res["hertz_cylinder"], res["hertz_sphere"]
    cr, sr = c["reference"], s3["reference"]
    fy2, fy3 = res["first_yield_cylinder"], res["first_yield_sphere"]
    conv, ld, pu = res["convergence"], res["load_displacement"], res["punch"]
    L = [f"{res['mode'].capitalize()} run; numbers in `results.json`. Steel, E = {study.E:g} MPa, nu = {study.NU}, "
         f"rigid cylinder/sphere R = {study.R:g} mm. Every solution used below certifies (worst relative KKT "
         f"residual <= {study.KKT_OK:g}, column `kkt`). 2D: conic solver; 3D: "
         f"{res.get('elastic_method_3d', study.elastic_method(3))} (elastic). Timings per comparison (s): {res['timings_s']}.", ""]

    L += ["## 1. Hertz, elastic limit", "",
          f"### Cylinder, plane strain (F = {cr['F']:g} N/mm: b = {cr['b']:.4f} mm, p0 = {cr['p0']:.1f} MPa)", "",
          "Reference: " + cr["formula"] + ". Block [-L, L] x [0, L] clamped on sides and top. Contact half-width "
          "from `summary()` (p^2 fit at the edge, clipped to the nodal bracket); peak pressure: largest lumped "
          "nodal pressure. `h_b`: contact-node spacing at x = b.", "",
          f"Mesh sequence, L = 20 b, grading 1.5 (rates of |difference| against h_b: b {c['rates']['b']:.2f}, "
          f"p0 {c['rates']['p0']:.2f}):", "",
          table(["nh", "elements", "h_b / b", "b - Hertz", "p_max - Hertz", "kkt", "time s"],
                [[r["nh"], r["n_elements"], f"{r['h_at_b_over_b']:.3f}", pct(r["b_err"]), pct(r["p0_err"]),
                  f"{r['kkt_worst']:.0e}", r["time_s"]] for r in c["mesh_sequence"]]), "",
          "Block sizes, grading 2, h_b about b/10 (the finite-block effect):", "",
          table(["L / b", "elements", "h_b / b", "b - Hertz", "p_max - Hertz", "max vm / p0", "depth fit / b", "kkt"],
                [[r["L_over_b"], r["n_elements"], f"{r['h_at_b_over_b']:.3f}", pct(r["b_err"]), pct(r["p0_err"]),
                  f"{r['vm_over_p0']:.4f}", f"{r['depth_fit_over_b']:.3f}", f"{r['kkt_worst']:.0e}"]
                 for r in c["block_sizes"]]), "",
          f"Extrapolated to L -> infinity assuming value = v_inf + c/L through the two largest blocks: "
          f"{json.dumps({k: round(v, 4) for k, v in c['extrapolated_block'].items()})}.", "",
          f"### Sphere, 3D quarter model (F = {sr['F']:g} N: a = {sr['a']:.4f} mm, p0 = {sr['p0']:.1f} MPa, "
          f"delta = a^2/R = {sr['delta']:.5f} mm)", "",
          "Reference: " + sr["formula"] + ". Quarter of the block [-L, L]^2 x [0, L], clamped on the outer "
          "faces and the top, symmetry planes x = 0 and y = 0. `h_a`: node spacing at r = a along the x axis. "
          "U is the rigid body's displacement; in the half-space it is the approach delta.", "",
          f"Mesh sequence, L = 8 a, grading 1.5 (rates: a {s3['rates']['a']:.2f}, p0 {s3['rates']['p0']:.2f}):", "",
          table(["n", "tets", "h_a / a", "a - Hertz", "p_max - Hertz", "U / delta", "kkt", "time s"],
                [[r["n"], r["n_elements"], f"{r['h_at_a_over_a']:.3f}", pct(r["a_err"]), pct(r["p0_err"]),
                  f"{r['U_over_delta']:.4f}", f"{r['kkt_worst']:.0e}", r["time_s"]] for r in s3["mesh_sequence"]]), "",
          "Block sizes (n chosen for about the same h_a):", "",
          table(["L / a", "n", "tets", "h_a / a", "a - Hertz", "p_max - Hertz", "U / delta", "max vm / p0", "kkt"],
                [[r["L_over_a"], r["n"], r["n_elements"], f"{r['h_at_a_over_a']:.3f}", pct(r["a_err"]),
                  pct(r["p0_err"]), f"{r['U_over_delta']:.4f}", f"{r['vm_over_p0']:.4f}", f"{r['kkt_worst']:.0e}"]
                 for r in s3["block_sizes"]]), "",
          f"Extrapolated to L -> infinity (v_inf + c/L, two largest blocks): "
          f"{json.dumps({k: round(v, 4) for k, v in s3['extrapolated_block'].items()})}.", ""]

    def last(rows, key):
        return rows[-1][key]

    L += ["## 2. First yield", "",
          "Reference: Green (2005) fits (docs/validation.md): cylinder max von Mises / p0 = "
          f"{cr['green_vm_over_p0']:.4f} at z = {cr['green_depth_over_b']:.3f} b; sphere "
          f"{sr['green_vm_over_p0']:.4f} at z = {sr['green_depth_over_a']:.3f} a.", "",
          "Ratio and depth from the elastic solutions of section 1 (depth: vertex of a parabola fitted to von "
          "Mises against depth over the near-axis elements within 10% of the axis maximum; the single largest "
          "element's centroid is in results.json):", "",
          table(["case", "mesh", "max vm / p0", "Green", "diff", "depth", "Green depth"],
                [["cylinder", f"L = {last(c['block_sizes'], 'L_over_b')} b, h_b = b/10",
                  f"{last(c['block_sizes'], 'vm_over_p0'):.4f}", f"{cr['green_vm_over_p0']:.4f}",
                  pct(last(c['block_sizes'], 'vm_over_p0') / cr['green_vm_over_p0'] - 1),
                  f"{last(c['block_sizes'], 'depth_fit_over_b'):.3f} b", f"{cr['green_depth_over_b']:.3f} b"],
                 ["cylinder, extrapolated L -> inf", "", f"{c['extrapolated_block']['vm_over_p0']:.4f}",
                  f"{cr['green_vm_over_p0']:.4f}",
                  pct(c['extrapolated_block']['vm_over_p0'] / cr['green_vm_over_p0'] - 1),
                  f"{c['extrapolated_block']['depth_fit_over_b']:.3f} b", ""],
                 ["sphere", f"L = {last(s3['mesh_sequence'], 'L_over_a')} a, n = {last(s3['mesh_sequence'], 'n')}",
                  f"{last(s3['mesh_sequence'], 'vm_over_p0'):.4f}", f"{sr['green_vm_over_p0']:.4f}",
                  pct(last(s3['mesh_sequence'], 'vm_over_p0') / sr['green_vm_over_p0'] - 1),
                  f"{last(s3['mesh_sequence'], 'depth_fit_over_a'):.3f} a", f"{sr['green_depth_over_a']:.3f} a"],
                 ["sphere, extrapolated L -> inf", "", f"{s3['extrapolated_block']['vm_over_p0']:.4f}",
                  f"{sr['green_vm_over_p0']:.4f}",
                  pct(s3['extrapolated_block']['vm_over_p0'] / sr['green_vm_over_p0'] - 1), "", ""]]), "",
          "Smallest force at which an element yields: below first yield the elasto-plastic solution is the "
          "elastic one, so it is the root of max von Mises(F) = sigma_y along elastic solutions. Hertz contact "
          "is not linear in F but self-similar (stresses ~ F^(1/2) in plane strain, F^(1/3) for the sphere): "
          "secant iteration on log(vm) against log(F), started with that exponent, stopped at |vm/sigma_y - 1| "
          "<= 1e-4.", "",
          table(["case", "sigma_y", "mesh", "F_yield computed", "F_yield from Green + Hertz", "diff", "solves",
                 "measured exponent"],
                [["cylinder", fy2["reference"]["sigma_y"], f"L = {fy2['mesh']['L_over_b']} b, nh = {fy2['mesh']['nh']}",
                  f"{fy2['F_yield']:.1f} N/mm", f"{fy2['reference']['F_yield']:.1f} N/mm", pct(fy2["F_err"]),
                  fy2["solves"], f"{fy2['measured_exponent']:.4f}"],
                 ["sphere", fy3["reference"]["sigma_y"], f"L = {fy3['mesh']['L_over_a']} a, n = {fy3['mesh']['n']}",
                  f"{fy3['F_yield']:.1f} N", f"{fy3['reference']['F_yield']:.1f} N", pct(fy3["F_err"]),
                  fy3["solves"], f"{fy3['measured_exponent']:.4f}"]]), "",
          f"Check with the elasto-plastic solver (H = 10 GPa) on the cylinder mesh: plastic elements at 0.99 "
          f"F_yield: {fy2['plastic_check']['below']['n_plastic']}, at 1.01 F_yield: "
          f"{fy2['plastic_check']['above']['n_plastic']}.", "",
          "Since p0 ~ F^(1/2) (2D) and F^(1/3) (3D), a force difference d corresponds to a p0/sigma_y difference "
          "of about d/2 and d/3.", ""]

    lv = conv["levels"]
    L += ["## 3. Mesh convergence of (2.1)", "",
          f"Problem: material, cylinder (R = {study.R:g}) and force ({conv['problem']['force']:g} N/mm, "
          f"sigma_y = {conv['problem']['yield_stress']:g}, H = {conv['problem']['hardening']:g}) of "
          f"problems/cylinder_2d.toml on the block [-{conv['problem']['L']:g}, {conv['problem']['L']:g}] x "
          f"[0, {conv['problem']['L']:g}], uniform meshes, nh doubling; reference: the finest mesh "
          f"(nh = {conv['finest']['nh']}, {conv['finest']['n_elements']} triangles, kkt "
          f"{conv['finest']['kkt_worst']:.0e}). Uniform meshes with doubled divisions are nested (worst "
          f"barycentric violation of a fine vertex in its coarse parent: "
          f"{max(r['nested_violation'] for r in lv):.1e}); coarse P0 stresses are injected into the fine "
          "elements and coarse P1 displacements interpolated at the fine nodes, both exactly. Errors: "
          "stresses in the energy norm [.,.]; strains of u in L2; u at the nodes in max norm; U; all relative "
          "to the finest solution. Rates: least-squares slope of log error against log h over the levels "
          "below (errors against the finest mesh, so the finest levels are biased low).", "",
          table(["nh", "h / h_finest", "elements", "e_sigma (energy)", "e_eps(u) (L2)", "e_u (max)", "e_U",
                 "plastic vol. share", "kkt"],
                [[r["nh"], f"{r['h_rel']:g}", r["n_elements"], f"{r['e_sigma_energy']:.3e}",
                  f"{r['e_strain_L2']:.3e}", f"{r['e_u_max']:.3e}", f"{r['e_U']:.3e}",
                  f"{r['plastic_volume_fraction']:.4f}", f"{r['kkt_worst']:.0e}"] for r in lv]), "",
          "Fitted rates: " + ", ".join(f"{k} {v:.2f}" for k, v in conv["rates"].items())
          + f"; Theorem 2 guarantees {conv['theorem_2_rate']} for the stresses.", ""]

    pts = ld["points"]
    L += ["## 4. Load-displacement", "",
          f"Cylinder problem (sigma_y = {ld['problem']['yield_stress']:g}, H = {ld['problem']['hardening']:g}) on "
          f"[-{ld['problem']['L']:g}, {ld['problem']['L']:g}] x [0, {ld['problem']['L']:g}], nh = "
          f"{ld['problem']['nh']}, grading {ld['problem']['grading']}, {ld['problem']['n_elements']} triangles; "
          "forces from 0.1 to 8 times the Green first-yield force. Elastic solutions on the same mesh and the "
          "Hertz half-width for comparison. Plastic zone: extent of the plastic element centroids.", "",
          table(["F (N/mm)", "U plastic", "U elastic", "b plastic", "b elastic", "Hertz b", "p_max plastic",
                 "plastic zone depth", "half-width", "plastic vol. share", "kkt"],
                [[f"{p['F']:.0f}", f"{p['plastic']['U']:.5f}", f"{p['elastic']['U']:.5f}",
                  f"{p['plastic']['contact_radius']:.3f}", f"{p['elastic']['contact_radius']:.3f}",
                  f"{p['hertz_b']:.3f}", f"{p['plastic']['max_contact_pressure']:.0f}",
                  f"{p['plastic']['zone']['depth']:.3f}", f"{p['plastic']['zone']['half_width']:.3f}",
                  f"{p['plastic']['plastic_volume_fraction']:.4f}",
                  f"{max(p['plastic']['kkt_worst'], p['elastic']['kkt_worst']):.0e}"] for p in pts]), "",
          f"The outermost node of Gamma_0 stayed inactive at every force: "
          f"{not any(p['plastic']['contact_zone_edge_active'] or p['elastic']['contact_zone_edge_active'] for p in pts)}.", ""]

    gm = pu["generator_mesh"]
    L += ["## 5. Perfect plasticity: flat punch (H = 0)", "",
          f"Reference: {pu['reference']['formula']}; sigma_y = {pu['reference']['sigma_y']:g}: p = "
          f"{pu['reference']['p_prandtl']:.1f} MPa. Punch half-width w = 1 mm (Gamma_0 = |x| <= w, obstacle "
          f"'flat'), block [-{pu['problem']['L']:g}, {pu['problem']['L']:g}] x [0, {pu['problem']['L']:g}] mm "
          "clamped on the sides and top.", "",
          "Approach: the limit load of (2.1) is the largest F for which (S) is feasible. It is computed directly "
          "as the SOCP max F subject to the constraints of (S) (equilibrium, force balance, lam >= 0, yield cones; "
          "`study.limit_load`), then confirmed by solving (S) at 0.99 and 1.01 times it "
          "(expected: converged, infeasible).", "",
          f"The built-in generator's two-triangle split locks: P1 displacements on it have no nonzero field "
          f"free of volume change, so no collapse mechanism exists and the discrete limit load is infinite. "
          f"Measured on nh = {gm['nh']}: the limit program is `{gm['limit_program_status']}` (unbounded), and "
          f"(S) at 3x the Prandtl force is `{gm['S_at_3x_prandtl']['status']}` (kkt "
          f"{gm['S_at_3x_prandtl']['kkt_worst']:.0e}) with U = {gm['S_at_3x_prandtl']['U']:.3f} mm and "
          f"{100 * gm['S_at_3x_prandtl']['plastic_element_share']:.0f}% of the elements plastic. The study "
          "therefore uses criss-cross meshes (each square cut into four triangles by its centre, "
          "`study.crossed_rectangle`), on which P1 does not lock:", "",
          table(["nh", "h / w", "triangles", "p_limit (MPa)", "p / Prandtl", "(S) at 0.99", "(S) at 1.01", "time s"],
                [[r["nh"], f"{r['h_over_w']:.4g}", r["n_elements"], f"{r['p_limit']:.1f}", f"{r['p_over_prandtl']:.4f}",
                  r["S_check"]["below"]["status"], r["S_check"]["above"]["status"], r["time_s"]]
                 for r in pu["mesh_sequence"]]), "",
          f"p_limit / Prandtl extrapolated linearly in h through the two finest meshes: "
          f"{pu['extrapolated_p_over_prandtl']:.4f}.", "",
          f"H -> 0 on nh = {pu['H_to_zero']['nh']} (discrete H = 0 limit force F_lim = "
          f"{pu['H_to_zero']['F_limit']:.1f} N/mm):", ""]
    for s in pu["H_to_zero"]["series"]:
        head = (f"F = {s['F_over_limit']} F_lim: the H = 0 problem is `{s['H0_status']}`"
                + (f", U = {s['H0_U']:.5f} mm" if s["H0_U"] is not None else ""))
        L += [head, "", table(["H / E", "U (mm)", "stress diff. to H = 0 (energy)", "max xi / sigma_y", "kkt"],
                              [[f"{r['H_over_E']:g}", f"{r['U']:.5g}",
                                f"{r['sigma_diff_to_H0']:.2e}" if "sigma_diff_to_H0" in r else "-",
                                f"{r['max_xi_over_sy']:.3g}", f"{r['kkt_worst']:.0e}"]
                               for r in s["hardening_sweep"]]), ""]
    L += ["## Figures", ""] + [f"![{f}]({f})" for f in FIGURES] + [""]
    return "\n".join(L)


def main(argv=None) -> int:
    return run_record(__doc__, "small meshes (under a minute)", HERE, TITLE, "validation study", lambda mode, out: run_all(mode), report, plots, argv)


if __name__ == "__main__":
    sys.exit(main())
