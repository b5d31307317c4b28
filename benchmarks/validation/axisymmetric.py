"""Validation of the meridian-plane model (issue 36): sphere and cone indentation of a
body of revolution against Hertz, a 3D quarter model of the same solid, the
elastic-plastic indentation literature and Oliver-Pharr's analysis.

    python benchmarks/validation/axisymmetric.py            # the record: axisymmetric.json, .md and two figures
    python benchmarks/validation/axisymmetric.py --quick    # coarse meshes, a few points, into quick/
    python benchmarks/validation/axisymmetric.py --report   # the report and the figures again, from the JSON

Units: N, mm, MPa; E = 200 GPa, nu = 0.3, a rigid sphere of radius R = 50 and a
contact radius near 1 (a / R = 0.02). Each elastic-plastic point fixes the geometry
and sets sigma_y = E* a0 / (Lambda R): with a small-strain model and a shallow sphere
the answer depends on Lambda = E* a / (sigma_y R), nu and H / E only, so every point is
solved on a mesh scaled to its contact. Every mesh is the graded generator's
(elastoplast/mesh/graded.py) with its growth rate made part of the mesh level, so
that a finer level is finer everywhere, not only at the contact.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from harness import run_record  # noqa: E402

import elastoplast as ep  # noqa: E402
from elastoplast.certificate.indentation import indentation_summary  # noqa: E402
from elastoplast.fem.material import von_mises  # noqa: E402
from elastoplast.io.loading_path import path_oliver_pharr  # noqa: E402
from elastoplast.mesh.graded import graded_mesh  # noqa: E402

HERE = Path(__file__).resolve().parent
TITLE = "Axisymmetric indentation: Hertz, a 3D quarter model, elastic-plastic spheres, Oliver-Pharr"
E, NU = 200e3, 0.3
E_STAR = E / (1 - NU**2)
R = 50.0
A0 = 1.0  # the contact radius each problem is scaled to
CONTACT_ZONE = 1.6  # Gamma_0: the bottom within this radius (a stays below it)
#: mesh levels: (h_contact / a0, growth of the element size per unit distance from the contact)
LEVELS = {"L1": (1 / 20, 0.2), "L2": (1 / 40, 0.1), "L3": (1 / 80, 0.05), "L4": (1 / 160, 0.025)}
BLOCK = 25.0  # the meridian block [0, 25] x [0, 25]: at least 20 contact radii for a <= 1.25
KKT_OK = 1e-6

SIZES = {
    "full": {
        "hertz_blocks": [5.0, 10.0, 20.0, 40.0, 80.0], "hertz_block_level": "L3",
        "hertz_levels": ["L1", "L2", "L3", "L4"],
        "quarter_h": [(0.2, 0.25), (0.14, 0.18), (0.1, 0.13), (0.07, 0.1), (0.05, 0.08)], "quarter_L": 8.0,
        "quarter_forces": [0.25, 0.5, 1.0],
        "lambdas": [1.0, 2.0, 3.0, 5.0, 10.0, 20.0, 30.0, 50.0, 100.0, 150.0],
        "hardenings": [1e-3, 1e-2], "sweep_levels": ["L1", "L2", "L3"],
        "locking_lambdas": [30.0, 100.0], "locking_levels": ["L1", "L2", "L3", "L4"],
        "pr_lambdas": [30.0, 50.0, 100.0], "pr_steps": [10, 20], "pr_level": "L2", "pr_levels": ["L1", "L2", "L3"],
        "beyond_lambdas": [300.0, 1000.0], "beyond_levels": ["L2", "L3"],
        "nu_values": [0.3, 0.49, 0.499], "nu_levels": ["L1", "L2", "L3", "L4"],
        "pattern_block": 12.0, "pattern_n": 80, "pattern_lambda": 100.0,
        "op_level": "L3", "op_levels": ["L1", "L2"], "op_lambda": 50.0, "op_cone_lambda": 30.0, "op_load": 10, "op_unload": 8,
    },
    "quick": {
        "hertz_blocks": [5.0, 20.0], "hertz_block_level": "L1", "hertz_levels": ["L1", "L2"],
        "quarter_h": [(0.4, 0.5), (0.3, 0.35)], "quarter_L": 8.0, "quarter_forces": [0.5, 1.0],
        "lambdas": [1.0, 3.0, 30.0, 100.0], "hardenings": [1e-3], "sweep_levels": ["L1"],
        "locking_lambdas": [30.0], "locking_levels": ["L1", "L2"],
        "pr_lambdas": [30.0], "pr_steps": [5], "pr_level": "L1", "pr_levels": ["L1"],
        "beyond_lambdas": [300.0], "beyond_levels": ["L1"], "nu_values": [0.3, 0.499], "nu_levels": ["L1", "L2"],
        "pattern_block": 12.0, "pattern_n": 24, "pattern_lambda": 100.0,
        "op_level": "L1", "op_levels": [], "op_lambda": 50.0, "op_cone_lambda": 30.0, "op_load": 5, "op_unload": 4,
    },
}


# ----------------------------------------------------------------------------
# literature (K. L. Johnson, Contact Mechanics, 1985, ch. 4 and 6)
# ----------------------------------------------------------------------------


def hertz(F: float) -> dict[str, float]:
    """Hertz's sphere on a half-space: a = (3FR/4E*)^(1/3), p0 = 3F/(2 pi a^2), delta = a^2/R."""
    a = (3 * F * R / (4 * E_STAR)) ** (1 / 3)
    return {"a": a, "p0": 3 * F / (2 * math.pi * a * a), "delta": a * a / R}


def cavity_pressure(lam: float) -> float:
    """Johnson's expanding-cavity mean pressure over sigma_y at Lambda = E* a / (sigma_y R):
    (c/a)^3 = [E a/(sigma_y R) + 4(1 - 2 nu)] / [6(1 - nu)], p/sigma_y = (2/3)[1 + ln (c/a)^3]."""
    ratio = (lam * (1 - NU**2) + 4 * (1 - 2 * NU)) / (6 * (1 - NU))
    return (2 / 3) * (1 + math.log(ratio))


def hertz_mean_pressure(lam: float) -> float:
    """Elastic mean pressure over sigma_y: p_m = 2 p0 / 3 = 4 E* a / (3 pi R)."""
    return 4 * lam / (3 * math.pi)


def pressure_guess(lam: float) -> float:
    """A first guess of p_m / sigma_y, only to choose the force (the measured a sets Lambda)."""
    return min(hertz_mean_pressure(lam), cavity_pressure(lam) + 0.3)


# ----------------------------------------------------------------------------
# problems
# ----------------------------------------------------------------------------


def meridian(level: str, sigma_y: float, H: float, force: float, *, block: float = BLOCK, shape: str = "sphere",
             half_angle: float | None = None, nu: float = NU) -> ep.Discretization:
    """The meridian block [0, block]^2 on a graded mesh of ``level``, default boundary
    (the lateral face and the top clamped, the axis free), a sphere of radius R or a cone."""
    hc, growth = LEVELS[level]
    obstacle = {"shape": shape, "radius": R} if shape == "sphere" else {"shape": shape, "half_angle": half_angle}
    data = {"mesh": {"generator": "graded", "size": [block, block], "contact_radius": CONTACT_ZONE,
                     "h_contact": 0.5, "h_far": block / 10, "axisymmetric": True},
            "material": {"E": E, "nu": nu, "yield_stress": sigma_y, "hardening": H},
            "obstacle": obstacle, "load": {"force": force}}
    problem = ep.problem_from_dict(data)
    mesh = graded_mesh([block, block], CONTACT_ZONE, hc * A0, block / 10, growth=growth)
    return ep.discretize(dataclasses.replace(problem, mesh=mesh))


def quarter_cylinder_mesh(L: float, hc: float, growth: float) -> ep.Mesh:
    """A 3D quarter of the cylinder of radius L and height L (the solid of revolution of
    the meridian square [0, L]^2), its base split at the contact zone, graded by the
    package's size field; facet groups xmin, ymin (symmetry planes), lateral, top,
    contact and bottom."""
    import gmsh

    from elastoplast.mesh.graded import _size_field, _to_mesh
    from elastoplast.mesh.topology import boundary_facets

    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("quarter-cylinder")
        occ = gmsh.model.occ
        body = occ.addCylinder(0.0, 0.0, 0.0, 0.0, 0.0, L, L, angle=math.pi / 2)
        disk = occ.addDisk(0.0, 0.0, 0.0, CONTACT_ZONE, CONTACT_ZONE)
        rect = occ.addRectangle(0.0, 0.0, 0.0, L, L)
        quarter, _ = occ.intersect([(2, disk)], [(2, rect)])
        occ.fragment([(3, body)], quarter)
        occ.synchronize()
        tol = 1e-3 * CONTACT_ZONE
        contact = [t for _, t in gmsh.model.getEntitiesInBoundingBox(-tol, -tol, -tol, CONTACT_ZONE + tol,
                                                                     CONTACT_ZONE + tol, tol, 2)]
        _size_field(gmsh, contact, 3, hc, L / 4, growth)
        gmsh.model.mesh.generate(3)
        raw = _to_mesh(gmsh, [L, L, L], CONTACT_ZONE, 3)
    finally:
        gmsh.finalize()
    points, cells = np.asarray(raw.points), np.asarray(raw.cells)
    facets = boundary_facets(cells)
    fx = points[facets]
    tol = 1e-9 * L
    rad = np.linalg.norm(fx[:, :, :2], axis=2)
    on = lambda axis, val: np.all(np.abs(fx[:, :, axis] - val) < tol, axis=1)  # noqa: E731
    base = on(2, 0.0)
    inside = np.all(rad <= CONTACT_ZONE * (1 + 1e-9), axis=1)
    groups = {"xmin": on(0, 0.0), "ymin": on(1, 0.0), "top": on(2, L), "contact": base & inside,
              "bottom": base & ~inside, "lateral": np.all(np.abs(rad - L) < 1e-6 * L, axis=1)}
    return ep.Mesh(points=points, cells=cells, groups={k: facets[m] for k, m in groups.items()})


def quarter_problem(mesh: ep.Mesh, force: float) -> ep.Discretization:
    """The elastic 3D quarter model: symmetry planes, lateral face and top clamped, a quarter of F."""
    problem = ep.Problem(mesh=mesh, material=ep.make_material(E, NU, 1e12, 1e4),
                         boundary=ep.Boundary(clamped=("lateral", "top"), contact=("contact",),
                                              fix_component={0: ("xmin",), 1: ("ymin",)}),
                         obstacle=ep.Obstacle(shape="sphere", dim=3, radius=R, center=(0.0, 0.0)), force=force / 4)
    return ep.discretize(problem)


def solve(disc: ep.Discretization, method: str = "newton") -> tuple[ep.Solution, float]:
    t0 = time.perf_counter()
    sol = ep.solve(disc, method, progress=False)
    if sol.status != ep.Status.CONVERGED or sol.kkt.worst > KKT_OK:
        sol = ep.solve(disc, "conic", progress=False)  # the reference when newton stalls
    return sol, time.perf_counter() - t0


def figures(disc: ep.Discretization, sol: ep.Solution, sigma_y: float | None = None) -> dict:
    """U, the indentation figures (a bracket, pressures, plastic zone, pile-up, c^2), KKT."""
    ind = indentation_summary(disc, sol, axisymmetric=disc.problem.axisymmetric)
    a_lo, a_hi = ind["contact_radius_active"], ind["contact_radius_free"]
    out = {"elements": int(disc.n_elements), "U": float(sol.U), "kkt": float(sol.kkt.worst),
           "status": sol.status.value, "a_active": a_lo, "a_free": a_hi, "a": 0.5 * (a_lo + a_hi),
           "p_mean": ind["mean_contact_pressure"], "p_mean_range": ind["mean_contact_pressure_range"],
           "p_peak": ind["peak_contact_pressure"], "c2": ind["contact_depth_ratio"], "pile_up": ind["pile_up"],
           "sink_in_at_edge": ind["sink_in_at_edge"], "plastic_depth": ind["plastic_zone_depth"],
           "plastic_radius": ind["plastic_zone_radius"], "vm_max": float(von_mises(np.asarray(sol.sigma)).max()),
           "plastic_elements": int(np.count_nonzero(sol.plastic))}
    if sigma_y is not None:
        out["Lambda"] = E_STAR * out["a"] / (sigma_y * R)
        out["Lambda_range"] = [E_STAR * a_lo / (sigma_y * R), E_STAR * a_hi / (sigma_y * R)]
        out["pm_over_sy"] = out["p_mean"] / sigma_y
    return out


# ----------------------------------------------------------------------------
# 1. Hertz
# ----------------------------------------------------------------------------


def hertz_force() -> float:
    """The force whose Hertz contact radius is a0: F = 4 E* a0^3 / (3 R)."""
    return 4 * E_STAR * A0**3 / (3 * R)


def hertz_case(level: str, block: float) -> dict:
    F = hertz_force()
    ref = hertz(F)
    disc = meridian(level, 1e12, 1e4, F, block=block)
    sol, t = solve(disc, "conic")
    f = figures(disc, sol)
    f.update(level=level, block=block, time_s=round(t, 2), a_in_bracket=bool(f["a_active"] <= ref["a"] <= f["a_free"]),
             a_err=f["a"] / ref["a"] - 1, p_peak_err=f["p_peak"] / ref["p0"] - 1,
             p_mean_err=f["p_mean"] / (2 * ref["p0"] / 3) - 1, U_over_delta=f["U"] / ref["delta"],
             vm_over_p0=f["vm_max"] / ref["p0"],
             # first yield: vm_max and a both grow as F^(1/3), so E* a / (vm_max R) is the Lambda at which
             # the largest von Mises stress reaches sigma_y
             Lambda_yield=E_STAR * ref["a"] / (f["vm_max"] * R),
             Lambda_yield_discrete_a=E_STAR * f["a"] / (f["vm_max"] * R))
    return f


def hertz_study(s: dict) -> dict:
    blocks = [hertz_case(s["hertz_block_level"], L) for L in s["hertz_blocks"]]
    levels = [hertz_case(lv, 20.0) for lv in s["hertz_levels"]]
    out = {"reference": hertz(hertz_force()), "force": hertz_force(), "blocks": blocks, "levels": levels}
    if len(blocks) >= 2:  # value = v_inf + c / L through the two largest blocks
        b1, b2 = blocks[-2], blocks[-1]
        inv1, inv2 = 1 / b1["block"], 1 / b2["block"]
        out["extrapolated"] = {k: b2[k] - (b1[k] - b2[k]) / (inv1 - inv2) * inv2
                               for k in ("U_over_delta", "p_peak_err", "a_err", "vm_over_p0")}
    return out


def quarter_study(s: dict) -> dict:
    """U(F) of the elastic quarter cylinder against the meridian model of the same solid."""
    L = s["quarter_L"]
    forces = [q * hertz_force() for q in s["quarter_forces"]]
    axi_disc = meridian("L4" if "L4" in s["hertz_levels"] else "L2", 1e12, 1e4, forces[-1], block=L)
    axi = []
    for F in forces:
        sol, _ = solve(axi_disc.with_force(F), "conic")
        axi.append(float(sol.U))
    rows = []
    for hc, growth in s["quarter_h"]:
        t0 = time.perf_counter()
        mesh = quarter_cylinder_mesh(L, hc, growth)
        disc = quarter_problem(mesh, forces[-1])
        Us, kkts = [], []
        for F in forces:
            sol, _ = solve(disc.with_force(F / 4), "newton")
            Us.append(float(sol.U))
            kkts.append(float(sol.kkt.worst))
        rows.append({"h_contact": hc, "growth": growth, "tetrahedra": int(disc.n_elements), "U": Us,
                     "diff": [u / v - 1 for u, v in zip(Us, axi)], "kkt": max(kkts),
                     "time_s": round(time.perf_counter() - t0, 1)})
        print(f"    quarter h = {hc}: {disc.n_elements} tets, U - U_axi {rows[-1]['diff']}", flush=True)
    return {"L": L, "forces": forces, "axi_elements": int(axi_disc.n_elements), "axi_U": axi,
            "hertz_delta": [hertz(F)["delta"] for F in forces], "rows": rows}


# ----------------------------------------------------------------------------
# 2. elastic-plastic sphere
# ----------------------------------------------------------------------------


def sphere_point(level: str, lam: float, h_ratio: float) -> dict:
    sigma_y = E_STAR * A0 / (lam * R)
    F = math.pi * A0**2 * pressure_guess(lam) * sigma_y
    disc = meridian(level, sigma_y, h_ratio * E, F)
    sol, t = solve(disc)
    f = figures(disc, sol, sigma_y)
    f.update(level=level, Lambda_target=lam, H_over_E=h_ratio, sigma_y=sigma_y, force=F, time_s=round(t, 2),
             U_over_a2R=f["U"] * R / f["a"] ** 2, pile_up_over_U=f["pile_up"] / f["U"],
             plastic_depth_over_a=f["plastic_depth"] / f["a"], plastic_radius_over_a=f["plastic_radius"] / f["a"])
    return f


def sweep_study(s: dict) -> dict:
    rows = []
    for level in s["sweep_levels"]:
        for h_ratio in s["hardenings"]:
            for lam in s["lambdas"]:
                rows.append(sphere_point(level, lam, h_ratio))
                r = rows[-1]
                print(f"    {level} H/E={h_ratio:g} Lambda={r['Lambda']:.3g}: pm/sy {r['pm_over_sy']:.3f} "
                      f"c2 {r['c2']:.3f} ({r['elements']} el, {r['time_s']} s)", flush=True)
    return {"rows": rows}


def locking_study(s: dict) -> dict:
    rows = []
    for lam in s["locking_lambdas"]:
        for level in s["locking_levels"]:
            rows.append(sphere_point(level, lam, 1e-3))
            r = rows[-1]
            print(f"    locking {level} Lambda={r['Lambda']:.3g}: pm/sy {r['pm_over_sy']:.4f} c2 {r['c2']:.4f} "
                  f"pile-up/U {r['pile_up_over_U']:.4f} ({r['elements']} el, {r['time_s']} s)", flush=True)
    return {"rows": rows}


def beyond_study(s: dict) -> dict:
    """Lambda beyond the sweep (H/E = 1e-3): where c^2 and p_m settle."""
    rows = [sphere_point(level, lam, 1e-3) for level in s["beyond_levels"] for lam in s["beyond_lambdas"]]
    for r in rows:
        print(f"    beyond {r['level']} Lambda={r['Lambda']:.4g}: pm/sy {r['pm_over_sy']:.3f} c2 {r['c2']:.3f} "
              f"pile-up/U {r['pile_up_over_U']:.4f}", flush=True)
    return {"rows": rows}


def incompressible_study(s: dict) -> dict:
    """Elastic Hertz as nu -> 1/2 on the graded levels: the element's volumetric locking
    measured against a closed form (delta = a^2 / R with E* = E / (1 - nu^2))."""
    rows = []
    for nu in s["nu_values"]:
        es = E / (1 - nu * nu)
        F = 4 * es * A0**3 / (3 * R)
        for level in s["nu_levels"]:
            disc = meridian(level, 1e12, 1e4, F, block=20.0, nu=nu)
            sol, t = solve(disc)
            f = figures(disc, sol)
            rows.append({"nu": nu, "level": level, "elements": f["elements"], "U_over_delta": f["U"] * R / A0**2,
                         "a": f["a"], "a_active": f["a_active"], "a_free": f["a_free"],
                         "p_peak_over_p0": f["p_peak"] / (3 * F / (2 * math.pi * A0**2)), "kkt": f["kkt"],
                         "time_s": round(t, 2)})
            print(f"    nu={nu} {level}: U/delta {rows[-1]['U_over_delta']:.4f}", flush=True)
    return {"rows": rows}


def pattern_case(axisymmetric: bool, pattern: str, s: dict) -> dict:
    """A structured graded rectangle, both triangle patterns on the same nodes, at Lambda near
    ``pattern_lambda``: a sphere in the meridian plane or a cylinder in plane strain (whole block)."""
    lam, L, n = s["pattern_lambda"], s["pattern_block"], s["pattern_n"]
    sigma_y = E_STAR * A0 / (lam * R)
    if axisymmetric:
        size, div, obstacle = [L, L], [n, n], {"shape": "sphere", "radius": R}
        F = math.pi * A0**2 * pressure_guess(lam) * sigma_y
    else:
        size, div, obstacle = [2 * L, L], [2 * n, n], {"shape": "cylinder", "radius": R}
        F = 2 * A0 * pressure_guess(lam) * sigma_y
    data = {"mesh": {"generator": "rectangle", "size": size, "divisions": div, "grading": 3.0,
                     "contact_radius": CONTACT_ZONE, "pattern": pattern, "axisymmetric": axisymmetric},
            "material": {"E": E, "nu": NU, "yield_stress": sigma_y, "hardening": 1e-3 * E},
            "obstacle": obstacle, "load": {"force": F}}
    disc = ep.discretize(ep.problem_from_dict(data))
    sol, t = solve(disc)
    f = figures(disc, sol, sigma_y)
    f.update(model="axisymmetric sphere" if axisymmetric else "plane-strain cylinder", pattern=pattern,
             pile_up_over_U=f["pile_up"] / f["U"], time_s=round(t, 1))
    print(f"    {f['model']} {pattern}: U {f['U']:.5g} c2 {f['c2']:.3f} pile-up/U {f['pile_up_over_U']:.4f} "
          f"({f['elements']} el, {f['time_s']} s)", flush=True)
    return f


def pattern_study(s: dict) -> dict:
    return {"rows": [pattern_case(axi, pattern, s) for axi in (False, True) for pattern in ("diagonal", "crossed")]}


def first_yield_study(s: dict, hertz_levels: list[dict]) -> dict:
    """Lambda at first yield from the elastic solves (section 1), confirmed by an
    elastic-plastic solve 2% below and above on the finest of those meshes."""
    finest = hertz_levels[-1]
    lam_y = finest["Lambda_yield"]
    checks = []
    F = hertz_force()
    for share in (0.98, 1.02):
        sigma_y = E_STAR * A0 / (share * lam_y * R)  # Lambda = share * Lambda_yield at this force (a = a0)
        disc = meridian(finest["level"], sigma_y, 1e-3 * E, F, block=20.0)
        sol, _ = solve(disc, "conic")
        checks.append({"Lambda_over_yield": share, "plastic_elements": int(np.count_nonzero(sol.plastic)),
                       "kkt": float(sol.kkt.worst)})
    return {"per_level": [{"level": h["level"], "elements": h["elements"], "Lambda_yield": h["Lambda_yield"],
                           "Lambda_yield_discrete_a": h["Lambda_yield_discrete_a"], "vm_over_p0": h["vm_over_p0"]}
                          for h in hertz_levels], "checks": checks,
            "hertz_green": (math.pi / 2) / 0.6199}


def prandtl_reuss_study(s: dict) -> dict:
    """Hencky against Prandtl-Reuss on the same monotone path of equal force steps up to F."""
    rows = []
    for lam, level in [(lam, level) for lam in s["pr_lambdas"] for level in s["pr_levels"]]:
        sigma_y = E_STAR * A0 / (lam * R)
        F = math.pi * A0**2 * pressure_guess(lam) * sigma_y
        disc = meridian(level, sigma_y, 1e-3 * E, F)
        hencky, _ = solve(disc)
        fh = figures(disc, hencky, sigma_y)
        for n in (s["pr_steps"] if level == s["pr_level"] else s["pr_steps"][:1]):
            t0 = time.perf_counter()
            forces = [F * (k + 1) / n for k in range(n)]
            res = ep.solve_path(disc, forces, "newton", progress=False)
            if not res.converged:
                res = ep.solve_path(disc, forces, "conic", progress=False)
            last = res.steps[-1]
            fp = figures(disc, dataclasses.replace(last.solution, u=last.u), sigma_y)
            rows.append({"Lambda_target": lam, "level": level, "steps": n, "elements": fh["elements"],
                         "converged": bool(res.converged), "U_hencky": fh["U"], "U_pr": fp["U"],
                         "U_diff": fp["U"] / fh["U"] - 1, "Lambda_hencky": fh["Lambda"], "Lambda_pr": fp["Lambda"],
                         "pm_hencky": fh["pm_over_sy"], "pm_pr": fp["pm_over_sy"], "c2_hencky": fh["c2"],
                         "c2_pr": fp["c2"], "pile_up_hencky": fh["pile_up"] / fh["U"],
                         "pile_up_pr": fp["pile_up"] / fp["U"], "plastic_hencky": fh["plastic_elements"],
                         "kkt_pr": max(st.solution.kkt.worst for st in res.steps),
                         "time_s": round(time.perf_counter() - t0, 1)})
            r = rows[-1]
            print(f"    PR {level} Lambda={lam:g} n={n}: U_PR/U_H - 1 = {r['U_diff']:+.4f}, c2 {r['c2_hencky']:.3f} -> "
                  f"{r['c2_pr']:.3f} ({r['time_s']} s)", flush=True)
    return {"rows": rows}


# ----------------------------------------------------------------------------
# 3. nanoindentation
# ----------------------------------------------------------------------------


def indentation_cycle(s: dict, shape: str, level: str | None = None) -> dict:
    """Load in equal steps to F_max, unload to 2% of it, Oliver-Pharr on the unloading."""
    level = level or s["op_level"]
    if shape == "sphere":
        lam = s["op_lambda"]
        sigma_y = E_STAR * A0 / (lam * R)
        half_angle = None
    else:  # a cone: a scales with the depth, Lambda = E* tan(beta) / sigma_y with beta = 90 deg - half angle
        half_angle = 70.3
        lam = s["op_cone_lambda"]
        sigma_y = E_STAR * math.tan(math.radians(90 - half_angle)) / lam
    F_max = math.pi * A0**2 * pressure_guess(lam) * sigma_y
    disc = meridian(level, sigma_y, 1e-3 * E, F_max, shape=shape, half_angle=half_angle)
    first = ep.solve(disc, "newton", progress=False)
    if first.status != ep.Status.CONVERGED:  # e.g. the cone's tip strains leave the small-strain model
        print(f"    OP {shape}: the Hencky solve at F_max ends {first.status.value}", flush=True)
        return {"shape": shape, "level": level, "elements": int(disc.n_elements), "sigma_y": sigma_y, "Lambda": lam,
                "half_angle": half_angle, "F_max": F_max, "refused": first.message, "status": first.status.value}
    n_load, n_unload = s["op_load"], s["op_unload"]
    forces = [F_max * (k + 1) / n_load for k in range(n_load)]
    forces += list(F_max * np.linspace(1.0, 0.02, n_unload + 1)[1:])
    t0 = time.perf_counter()
    res = ep.solve_path(disc, forces, "newton", progress=False)
    if not res.converged:
        res = ep.solve_path(disc, forces, "conic", progress=False)
    op = path_oliver_pharr(disc, res)
    peak = res.steps[n_load - 1]
    fp = figures(disc, dataclasses.replace(peak.solution, u=peak.u), sigma_y if shape == "sphere" else None)
    a = fp["a"]
    true_area = math.pi * a * a
    out = {"shape": shape, "level": level, "elements": int(disc.n_elements), "sigma_y": sigma_y, "Lambda": lam,
           "half_angle": half_angle, "radius": R if shape == "sphere" else None, "forces": [st.force for st in res.steps],
           "U": [st.U for st in res.steps], "converged": bool(res.converged),
           "kkt": max(st.solution.kkt.worst for st in res.steps), "time_s": round(time.perf_counter() - t0, 1),
           "oliver_pharr": op, "peak": fp, "true_area": true_area, "true_hardness": F_max / true_area}
    if op is not None and math.isfinite(op["A"]):
        out["E_r_true_area"] = math.sqrt(math.pi) * op["S"] / (2 * math.sqrt(true_area))
        out["hardness_over_true"] = op["hardness"] / out["true_hardness"]
        out["area_over_true"] = op["A"] / true_area
        # the cone's own geometry constant 2 (pi - 2) / pi = 0.727 in place of 0.75
        h_c72 = op["h_max"] - 0.72 * op["F_max"] / op["S"]
        if shape == "cone":
            A72 = math.pi * math.tan(math.radians(half_angle)) ** 2 * h_c72**2
            out["eps_072"] = {"h_c": h_c72, "A": A72, "hardness": op["F_max"] / A72,
                              "E_r": math.sqrt(math.pi) * op["S"] / (2 * math.sqrt(A72))}
        # Sneddon: the unloading stiffness of a half-space is 2 E* a for any axisymmetric punch
        out["S_over_sneddon"] = op["S"] / (2 * E_STAR * a)
    print(f"    OP {shape}: E_r/E* {op and op['E_r'] / op['E_star']}, H/true {out.get('hardness_over_true')}",
          flush=True)
    return out


# ----------------------------------------------------------------------------
# the record
# ----------------------------------------------------------------------------


def measure(mode: str, out: Path) -> dict:
    s = SIZES[mode]
    res: dict = {"mode": mode, "sizes": s, "levels": LEVELS, "E": E, "nu": NU, "R": R, "block": BLOCK}
    timings = {}

    def timed(name, fn):
        t0 = time.perf_counter()
        print(f"  {name} ...", flush=True)
        res[name] = fn()
        timings[name] = round(time.perf_counter() - t0, 1)
        print(f"  {name}: {timings[name]} s", flush=True)

    timed("hertz", lambda: hertz_study(s))
    timed("first_yield", lambda: first_yield_study(s, res["hertz"]["levels"]))
    timed("quarter", lambda: quarter_study(s))
    timed("sweep", lambda: sweep_study(s))
    timed("locking", lambda: locking_study(s))
    timed("beyond", lambda: beyond_study(s))
    timed("incompressible", lambda: incompressible_study(s))
    timed("patterns", lambda: pattern_study(s))
    timed("prandtl_reuss", lambda: prandtl_reuss_study(s))
    timed("nano_sphere", lambda: indentation_cycle(s, "sphere"))
    timed("nano_sphere_levels", lambda: [indentation_cycle(s, "sphere", lv) for lv in s["op_levels"]])
    timed("nano_cone", lambda: indentation_cycle(s, "cone"))
    res["timings_s"] = timings
    return res


def render(res: dict) -> str:
    from axisymmetric_report import render_report

    return render_report(res)


def plots(res: dict, out: Path) -> None:
    from axisymmetric_report import draw

    draw(res, out)


def main(argv=None) -> int:
    sys.path.insert(0, str(HERE))
    return run_record(__doc__, "coarse meshes and a few points, about two minutes", HERE, TITLE,
                      "axisymmetric validation", measure, render, plots, argv=argv, study="axisymmetric")


if __name__ == "__main__":
    raise SystemExit(main())
