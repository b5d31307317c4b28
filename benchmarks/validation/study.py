"""The comparisons of the validation study (issue 5), one function each.

Every function returns a plain dict (JSON-ready) holding the outside reference,
the meshes and the measured differences. Sizes come in as arguments so that
``run.py --quick`` and the test suite run the same code on smaller meshes.

Steel throughout (N, mm, MPa): E = 200 GPa, nu = 0.3. The rigid cylinder and
sphere have R = 40 mm; the reference forces give a Hertz half-width / radius of
about 1 mm.
"""

from __future__ import annotations

import math
import time
import warnings
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

import elastoplast as ep
from elastoplast.certificate.kkt import energy_norm_sq
from elastoplast.fem.material import von_mises
from elastoplast.certificate.solution import Status, summary

try:
    from . import references as ref
except ImportError:  # run as a script or loaded by path
    import references as ref  # type: ignore[no-redef]

E, NU, R = 200_000.0, 0.3, 40.0
#: plane-strain force per mm giving b = 1.0 mm (docs/validation.md)
F_CYLINDER = 4315.0
#: sphere force giving a = 1.0 mm
F_SPHERE = 7330.0
#: a yield stress this far above every stress is the elastic limit
ELASTIC = 1e12
#: yield stresses of the first-yield study (those of problems/*.toml)
SY_CYLINDER, SY_SPHERE = 1200.0, 1500.0
#: a solution is trusted when its worst relative KKT residual stays below this
KKT_OK = 1e-6


# ----------------------------------------------------------------------------
# problems
# ----------------------------------------------------------------------------


def cylinder_problem(L: float, nh: int, grading: float, force: float, *, yield_stress: float = ELASTIC,
                     hardening: float = 1e4, contact_radius: float = 2.5, radius: float = R) -> ep.Problem:
    """Plane strain: the block ``[-L, L] x [0, L]`` clamped but at the bottom, ``2nh x nh`` cells."""
    return ep.problem_from_dict({
        "mesh": {"generator": "rectangle", "size": [2 * L, L], "divisions": [2 * nh, nh], "grading": grading,
                 "contact_radius": min(contact_radius, 0.8 * L)},
        "material": {"E": E, "nu": NU, "yield_stress": yield_stress, "hardening": hardening},
        "obstacle": {"shape": "cylinder", "radius": radius},
        "load": {"force": force},
    })


def sphere_quarter_problem(L: float, n: int, grading: float, force: float, *, yield_stress: float = ELASTIC,
                           hardening: float = 1e4, contact_radius: float = 2.0) -> ep.Problem:
    """Quarter of the block ``[-L, L]^2 x [0, L]`` (symmetry planes x = 0, y = 0), ``n^3`` cells,
    carrying ``force / 4``. The generated mesh is mirror-symmetric, so this is exact."""
    return ep.problem_from_dict({
        "mesh": {"generator": "box", "origin": [0.0, 0.0, 0.0], "size": [L, L, L], "divisions": [n, n, n],
                 "grading": grading, "contact_radius": min(contact_radius, 0.8 * L)},
        "material": {"E": E, "nu": NU, "yield_stress": yield_stress, "hardening": hardening},
        "boundary": {"clamped": ["xmax", "ymax", "top"], "fix_component": {"x": ["xmin"], "y": ["ymin"]}},
        "obstacle": {"shape": "sphere", "radius": R},
        "load": {"force": force / 4.0},
    })


def crossed_rectangle(L: float, nh: int, half_width: float) -> ep.Mesh:
    """``[-L, L] x [0, L]`` in ``2nh x nh`` squares, each cut into four triangles by its centre
    ("criss-cross"). Unlike the generator's two-triangle split, this mesh has nonzero
    piecewise-linear fields free of volume change, so P1 does not lock in plasticity.
    Groups as the built-in generator names them; ``contact``: bottom edges within ``|x| <= w``."""
    nx, ny = 2 * nh, nh
    x, y = np.linspace(-L, L, nx + 1), np.linspace(0.0, L, ny + 1)
    X, Y = np.meshgrid(x, y, indexing="ij")
    corners = np.stack([X.ravel(), Y.ravel()], axis=1)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    i, j = i.ravel(), j.ravel()
    node = lambda a, b: a * (ny + 1) + b  # noqa: E731
    centre = corners.shape[0] + np.arange(i.size)
    mids = np.stack([0.5 * (x[i] + x[i + 1]), 0.5 * (y[j] + y[j + 1])], axis=1)
    ring = [node(i, j), node(i + 1, j), node(i + 1, j + 1), node(i, j + 1)]
    cells = np.concatenate([np.stack([ring[k], ring[(k + 1) % 4], centre], axis=1) for k in range(4)])
    points = np.concatenate([corners, mids])
    k = np.arange(nx)
    bottom = np.stack([node(k, 0), node(k + 1, 0)], axis=1)
    top = np.stack([node(k, ny), node(k + 1, ny)], axis=1)
    m = np.arange(ny)
    groups = {"xmin": np.stack([node(0, m), node(0, m + 1)], axis=1),
              "xmax": np.stack([node(nx, m), node(nx, m + 1)], axis=1),
              "bottom": bottom, "top": top,
              "contact": bottom[np.all(np.abs(points[bottom][:, :, 0]) <= half_width * (1 + 1e-12), axis=1)]}
    return ep.Mesh(points=points, cells=cells.astype(np.int64), groups=groups)


def punch_problem(L: float, nh: int, force: float, *, half_width: float = 1.0, yield_stress: float = 1000.0,
                  hardening: float = 0.0, crossed: bool = True) -> ep.Problem:
    """Rigid flat punch of half-width ``w`` on the block ``[-L, L] x [0, L]``, uniform mesh,
    criss-cross (``crossed``) or the built-in generator's. Clamped on the sides and top.

    Gamma_0 is exactly the punch face ``|x| <= w`` (a node sits at ``x = +-w`` when
    ``nh * w / L`` is an integer); the rest of the bottom is free.
    """
    if crossed:
        mesh = crossed_rectangle(L, nh, half_width)
    else:
        mesh = ep.structured_mesh([2 * L, L], [2 * nh, nh], half_width)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # H = 0: the perfect-plasticity warning is the point here
        material = ep.make_material(E, NU, yield_stress, hardening)
    return ep.Problem(mesh=mesh, material=material,
                      boundary=ep.Boundary(clamped=("xmin", "xmax", "top"), contact=("contact",)),
                      obstacle=ep.Obstacle(shape="flat", dim=2, center=(0.0,)), force=float(force))


# ----------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------


def centroids(disc: ep.Discretization) -> np.ndarray:
    return disc.mesh.points[disc.mesh.cells].mean(axis=1)


def solve(disc: ep.Discretization, method: str = "conic", **options: Any) -> ep.Solution:
    """``ep.solve`` that refuses silently bad answers: a converged solution must certify."""
    sol = ep.solve(disc, method, **options)
    if sol.status is Status.CONVERGED and not sol.kkt.worst <= KKT_OK:
        raise RuntimeError(f"{method} says converged but the worst KKT residual is {sol.kkt.worst:.2e}")
    return sol


def elastic_method(dim: int) -> str:
    """Uzawa where it exists (measured 5x to 18x faster than the conic solver on the
    quarter sphere, 10k and 25k tetrahedra), else the conic reference; 2D uses conic."""
    return "uzawa" if dim == 3 and "uzawa" in ep.METHODS else "conic"


def solve_elastic(disc: ep.Discretization) -> ep.Solution:
    method = elastic_method(disc.dim)
    return solve(disc, method, tol=1e-9) if method == "uzawa" else solve(disc, method)


def contact_spacing(disc: ep.Discretization, at: float) -> float:
    """Spacing of the contact nodes around the distance ``at`` from the obstacle centre
    (in 3D: along the x axis, the nodes with y = 0)."""
    pts = disc.mesh.points[disc.contact_nodes]
    if disc.dim == 3:
        pts = pts[np.abs(pts[:, 1]) < 1e-12]
    x = np.unique(np.abs(pts[:, 0]))
    i = min(max(int(np.searchsorted(x, at)), 1), x.size - 1)
    return float(x[i] - x[i - 1])


def von_mises_peak(disc: ep.Discretization, sol: ep.Solution, length: float) -> dict[str, float]:
    """Largest von Mises stress and where it sits below the contact centre.

    ``depth_element``: centroid depth of the element holding the maximum.
    ``depth_fit``: vertex of a least-squares parabola of von Mises against depth over the
    elements whose centroid lies within ``0.2 length`` of the symmetry axis and whose
    von Mises exceeds 90% of the axis maximum (P0 stresses make the single element noisy).
    """
    vm = von_mises(sol.sigma)
    c = centroids(disc)
    i = int(np.argmax(vm))
    z = c[:, -1]
    off_axis = np.linalg.norm(c[:, :-1] - np.asarray(disc.problem.obstacle.center), axis=1)
    near = off_axis <= 0.2 * length
    depth_fit = float("nan")
    if near.sum() >= 5:
        sel = near & (vm >= 0.9 * vm[near].max())
        if np.unique(np.round(z[sel], 12)).size >= 3:
            c2, c1, _ = np.polyfit(z[sel], vm[sel], 2)
            if c2 < 0:
                depth_fit = float(-c1 / (2 * c2))
    return {"max": float(vm[i]), "depth_element": float(z[i]), "off_axis_element": float(off_axis[i]),
            "depth_fit": depth_fit}


def plastic_zone(disc: ep.Discretization, sol: ep.Solution) -> dict[str, float]:
    """Extent of the plastic elements (centroids): deepest point, widest in-plane reach."""
    if not sol.plastic.any():
        return {"depth": 0.0, "half_width": 0.0, "top": float("nan")}
    c = centroids(disc)[sol.plastic]
    r = np.linalg.norm(c[:, :-1] - np.asarray(disc.problem.obstacle.center), axis=1)
    return {"depth": float(c[:, -1].max()), "half_width": float(r.max()), "top": float(c[:, -1].min())}


def fit_rate(h: Sequence[float], err: Sequence[float]) -> float:
    """Least-squares slope of log(err) against log(h)."""
    h, err = np.asarray(h, float), np.asarray(err, float)
    ok = err > 0
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(h[ok]), np.log(err[ok]), 1)[0])


def run_record(disc: ep.Discretization, sol: ep.Solution) -> dict[str, Any]:
    s = summary(disc, sol)
    return {"n_elements": disc.n_elements, "method": sol.method, "status": sol.status.value,
            "iterations": sol.iterations, "time_s": round(sol.time_s, 3), "kkt_worst": sol.kkt.worst,
            "U": sol.U, "max_contact_pressure": s["max_contact_pressure"], "contact_radius": s["contact_radius"],
            "plastic_volume_fraction": s["plastic_volume_fraction"]}


# ----------------------------------------------------------------------------
# 1. Hertz, elastic limit
# ----------------------------------------------------------------------------


def hertz_cylinder_study(mesh_nh: Sequence[int], block_L: Sequence[float], *, mesh_L: float = 20.0,
                         block_h: float = 0.1) -> dict[str, Any]:
    """2D cylinder: contact half-width and peak pressure against Hertz.

    Mesh sequence: block half-width ``mesh_L`` (in units of b), grading 1.5, ``nh``
    doubling. Block sizes: grading 2 with ``nh`` chosen so that the contact-node
    spacing at ``x = b`` is about ``block_h * b`` (for the power law it is
    ``2 sqrt(L b) / nh``). Everything else also feeds the first-yield ratio.
    """
    hz = ref.hertz_cylinder(F_CYLINDER, R, E, NU)
    b, p0 = hz["b"], hz["p0"]
    green = ref.green_first_yield_cylinder(NU)

    def one(L: float, nh: int, grading: float) -> dict[str, Any]:
        disc = ep.discretize(cylinder_problem(L * b, nh, grading, F_CYLINDER))
        sol = solve_elastic(disc)
        rec = run_record(disc, sol)
        peak = von_mises_peak(disc, sol, b)
        rec.update({
            "L_over_b": L, "nh": nh, "grading": grading, "h_at_b_over_b": contact_spacing(disc, b) / b,
            "b_err": rec["contact_radius"] / b - 1.0, "p0_err": rec["max_contact_pressure"] / p0 - 1.0,
            "vm_over_p0": peak["max"] / p0, "vm_over_pmax": peak["max"] / rec["max_contact_pressure"],
            "depth_element_over_b": peak["depth_element"] / b, "depth_fit_over_b": peak["depth_fit"] / b,
        })
        return rec

    mesh = [one(mesh_L, nh, 1.5) for nh in mesh_nh]
    block = [one(L, int(math.ceil(2.0 * math.sqrt(L) / block_h)), 2.0) for L in block_L]
    return {"reference": {"formula": "b = sqrt(4 F R / (pi E*)), p0 = 2F / (pi b) (docs/validation.md)", "F": F_CYLINDER,
                          "R": R, "E": E, "nu": NU, "b": b, "p0": p0,
                          "green_vm_over_p0": 1.0 / green["p0_over_sy"], "green_depth_over_b": green["depth_over_b"]},
            "mesh_sequence": mesh, "block_sizes": block,
            "rates": {"b": fit_rate([m["h_at_b_over_b"] for m in mesh], [abs(m["b_err"]) for m in mesh]),
                      "p0": fit_rate([m["h_at_b_over_b"] for m in mesh], [abs(m["p0_err"]) for m in mesh])},
            "extrapolated_block": extrapolate_in_inverse_size(block, "L_over_b",
                                                              ["vm_over_p0", "p0_err", "b_err", "depth_fit_over_b"])}


def hertz_sphere_study(mesh_n: Sequence[int], block_L: Sequence[float], block_n: Sequence[int], *,
                       mesh_L: float = 8.0) -> dict[str, Any]:
    """3D sphere (quarter model): contact radius, peak pressure and approach ``U`` against Hertz.

    Mesh sequence: quarter block of side ``mesh_L`` (units of a), grading 1.5, ``n`` growing.
    Block sizes: ``block_L`` with ``block_n`` chosen to keep the node spacing at r = a about
    equal (power law: ``1.5 L (a / L)^(1/3) / n``).
    """
    hz = ref.hertz_sphere(F_SPHERE, R, E, NU)
    a, p0, delta = hz["a"], hz["p0"], hz["delta"]
    green = ref.green_first_yield_sphere(NU)

    def one(L: float, n: int) -> dict[str, Any]:
        disc = ep.discretize(sphere_quarter_problem(L * a, n, 1.5, F_SPHERE))
        sol = solve_elastic(disc)
        rec = run_record(disc, sol)
        peak = von_mises_peak(disc, sol, a)
        rec.update({
            "L_over_a": L, "n": n, "h_at_a_over_a": contact_spacing(disc, a) / a,
            "a_err": rec["contact_radius"] / a - 1.0, "p0_err": rec["max_contact_pressure"] / p0 - 1.0,
            "U_over_delta": sol.U / delta, "vm_over_p0": peak["max"] / p0,
            "vm_over_pmax": peak["max"] / rec["max_contact_pressure"],
            "depth_element_over_a": peak["depth_element"] / a, "depth_fit_over_a": peak["depth_fit"] / a,
        })
        return rec

    mesh = [one(mesh_L, n) for n in mesh_n]
    block = [one(L, n) for L, n in zip(block_L, block_n)]
    return {"reference": {"formula": "a = (3FR/4E*)^(1/3), p0 = 3F/(2 pi a^2), delta = a^2/R (docs/validation.md)",
                          "F": F_SPHERE, "R": R, "E": E, "nu": NU, "a": a, "p0": p0, "delta": delta,
                          "green_vm_over_p0": 1.0 / green["p0_over_sy"], "green_depth_over_a": green["depth_over_a"]},
            "mesh_sequence": mesh, "block_sizes": block,
            "rates": {k: fit_rate([m["h_at_a_over_a"] for m in mesh], [abs(m[e]) for m in mesh])
                      for k, e in (("a", "a_err"), ("p0", "p0_err"))},
            "extrapolated_block": extrapolate_in_inverse_size(block, "L_over_a",
                                                              ["U_over_delta", "vm_over_p0", "p0_err", "a_err"])}


def extrapolate_in_inverse_size(rows: list[dict], size_key: str, keys: Sequence[str]) -> dict[str, float]:
    """Value at infinite block size, assuming ``value = v_inf + c / L`` through the two largest blocks."""
    if len(rows) < 2:
        return {}
    r1, r2 = sorted(rows, key=lambda r: r[size_key])[-2:]
    L1, L2 = r1[size_key], r2[size_key]
    return {k: float((L2 * r2[k] - L1 * r1[k]) / (L2 - L1)) for k in keys}


# ----------------------------------------------------------------------------
# 2. First yield
# ----------------------------------------------------------------------------


def first_yield_force(disc: ep.Discretization, yield_stress: float, exponent: float, *, rtol: float = 1e-4,
                      max_solves: int = 8) -> dict[str, Any]:
    """Smallest force at which an element reaches von Mises = ``yield_stress``, by elastic solves.

    Below first yield the elasto-plastic solution is the elastic one, so the answer is the root
    of ``max von Mises (F) = sigma_y`` along elastic solutions. Hertz contact is not linear in F
    (the contact zone grows), but it is self-similar: on a half-space the stresses scale as
    ``F^exponent`` (1/2 in plane strain, 1/3 for the sphere). The iteration is the secant method
    on ``log vm`` against ``log F`` started from that exponent; it stops when ``vm / sigma_y``
    is within ``rtol`` of 1.
    """
    F = disc.force
    hist = []
    slope = exponent
    for _ in range(max_solves):
        sol = solve_elastic(disc.with_force(F))
        vm = float(von_mises(sol.sigma).max())
        hist.append({"F": F, "vm_over_sy": vm / yield_stress})
        if abs(vm / yield_stress - 1.0) <= rtol:
            break
        if len(hist) >= 2:
            (F1, v1), (F2, v2) = [(h["F"], h["vm_over_sy"]) for h in hist[-2:]]
            if F1 != F2 and v1 != v2:
                slope = math.log(v2 / v1) / math.log(F2 / F1)
        F = F * (yield_stress / vm) ** (1.0 / slope)
    return {"F_yield": hist[-1]["F"], "solves": len(hist), "history": hist, "measured_exponent": slope}


def confirm_first_yield(problem_at: Any, F_yield: float, yield_stress: float, margin: float = 0.01) -> dict[str, Any]:
    """Elasto-plastic solves (H = 10 GPa) just below and above ``F_yield``: plastic element counts."""
    out = {}
    for name, factor in (("below", 1.0 - margin), ("above", 1.0 + margin)):
        disc = ep.discretize(problem_at(F_yield * factor, yield_stress))
        sol = solve(disc, "conic")
        out[name] = {"F": F_yield * factor, "n_plastic": int(sol.plastic.sum()), "kkt_worst": sol.kkt.worst,
                     "status": sol.status.value}
    return out


def first_yield_cylinder(L: float, nh: int, grading: float = 1.5) -> dict[str, Any]:
    green = ref.green_first_yield_cylinder(NU)
    p0_green = green["p0_over_sy"] * SY_CYLINDER
    F_green = ref.cylinder_force_for_p0(p0_green, R, E, NU)
    b = ref.hertz_cylinder(F_green, R, E, NU)["b"]
    make = lambda F, sy: cylinder_problem(L * b, nh, grading, F, yield_stress=sy)  # noqa: E731
    disc = ep.discretize(make(F_green, ELASTIC))
    fy = first_yield_force(disc, SY_CYLINDER, 0.5)
    check = confirm_first_yield(make, fy["F_yield"], SY_CYLINDER)
    return {"reference": {"formula": "Green: p0/sy = 1.164 + 2.975 nu - 2.906 nu^2; F = pi R p0^2 / E*",
                          "sigma_y": SY_CYLINDER, "p0_yield": p0_green, "F_yield": F_green},
            "mesh": {"L_over_b": L, "nh": nh, "grading": grading, "n_elements": disc.n_elements},
            **fy, "F_err": fy["F_yield"] / F_green - 1.0, "plastic_check": check}


def first_yield_sphere(L: float, n: int) -> dict[str, Any]:
    green = ref.green_first_yield_sphere(NU)
    p0_green = green["p0_over_sy"] * SY_SPHERE
    F_green = ref.sphere_force_for_p0(p0_green, R, E, NU)
    a = ref.hertz_sphere(F_green, R, E, NU)["a"]
    disc = ep.discretize(sphere_quarter_problem(L * a, n, 1.5, F_green))
    fy = first_yield_force(disc, SY_SPHERE, 1.0 / 3.0)
    # the quarter model carries a quarter of the force: report the full sphere's
    fy["F_yield"] *= 4.0
    for h in fy["history"]:
        h["F"] *= 4.0
    return {"reference": {"formula": "Green: p0/sy = 1.30075 + 0.87825 nu + 0.54373 nu^2; F = pi^3 R^2 p0^3 / (6 E*^2)",
                          "sigma_y": SY_SPHERE, "p0_yield": p0_green, "F_yield": F_green},
            "mesh": {"L_over_a": L, "n": n, "grading": 1.5, "n_elements": disc.n_elements},
            **fy, "F_err": fy["F_yield"] / F_green - 1.0}


# ----------------------------------------------------------------------------
# 3. Mesh convergence of (2.1)
# ----------------------------------------------------------------------------


def locate(coarse: ep.Mesh, points: np.ndarray, candidates: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Element of ``coarse`` containing each point and the barycentric coordinates there."""
    X = coarse.points[coarse.cells]
    tree = cKDTree(X.mean(axis=1))
    _, near = tree.query(points, k=min(candidates, coarse.n_elements))
    best = np.full(points.shape[0], -1)
    bary = np.zeros((points.shape[0], coarse.dim + 1))
    score = np.full(points.shape[0], -np.inf)
    for j in range(near.shape[1]):
        el = near[:, j]
        T = np.swapaxes(X[el, 1:] - X[el, :1], 1, 2)
        lam = np.linalg.solve(T, (points - X[el, 0])[:, :, None])[:, :, 0]
        full = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
        s = full.min(axis=1)
        better = s > score
        best[better], score[better], bary[better] = el[better], s[better], full[better]
    return best, bary


def transfer(coarse: ep.Discretization, sol_c: ep.Solution, fine: ep.Discretization) -> dict[str, Any]:
    """Coarse P0 stresses and P1 displacements on the fine mesh.

    The meshes are checked to be nested (every fine vertex lies in the coarse element
    containing the fine centroid); then the P0 field is injected exactly and the P1 field
    interpolated exactly.
    """
    parent, _ = locate(coarse.mesh, centroids(fine))
    Xc = coarse.mesh.points[coarse.mesh.cells[parent]]
    nested_worst = 0.0
    for v in range(fine.dim + 1):
        p = fine.mesh.points[fine.mesh.cells[:, v]]
        T = np.swapaxes(Xc[:, 1:] - Xc[:, :1], 1, 2)
        lam = np.linalg.solve(T, (p - Xc[:, 0])[:, :, None])[:, :, 0]
        b = np.concatenate([1.0 - lam.sum(axis=1, keepdims=True), lam], axis=1)
        nested_worst = max(nested_worst, float(-b.min()))
    el, bary = locate(coarse.mesh, fine.mesh.points)
    u = np.einsum("nv,nvd->nd", bary, sol_c.u[coarse.mesh.cells[el]])
    return {"sigma": sol_c.sigma[parent], "xi": sol_c.xi[parent], "u": u, "nested_violation": nested_worst}


def convergence_study(nh: Sequence[int], *, L: float = 4.0, grading: float = 1.0, force: float = F_CYLINDER,
                      yield_stress: float = SY_CYLINDER, hardening: float = 1e4) -> dict[str, Any]:
    """Errors of (2.1) against the finest mesh: the material, obstacle and force of
    problems/cylinder_2d.toml on a ``[-L, L] x [0, L]`` block, ``nh`` doubling.

    Uniform meshes (grading 1) are nested when ``nh`` doubles (graded ones are not: the
    power law moves the midpoints off the coarse diagonals); :func:`transfer` measures it.
    """
    levels = []
    for n in nh:
        disc = ep.discretize(cylinder_problem(L, n, grading, force, yield_stress=yield_stress, hardening=hardening,
                                              contact_radius=4.0))
        sol = solve(disc, "conic")
        levels.append((n, disc, sol))
    n_f, fine, sf = levels[-1]
    ref_norm = math.sqrt(energy_norm_sq(fine, sf.sigma, sf.xi))
    eps_f = fine.strain(fine.free_displacement(sf.u))
    vol = fine.volumes
    strain_norm = math.sqrt(float(vol @ np.sum(eps_f**2, axis=1)))
    rows = []
    for n, disc, sol in levels[:-1]:
        t = transfer(disc, sol, fine)
        e_sigma = math.sqrt(energy_norm_sq(fine, sf.sigma - t["sigma"], sf.xi - t["xi"])) / ref_norm
        eps_c = fine.strain(fine.free_displacement(t["u"]))
        e_strain = math.sqrt(float(vol @ np.sum((eps_f - eps_c) ** 2, axis=1))) / strain_norm
        e_u_max = float(np.abs(sf.u - t["u"]).max() / np.abs(sf.u).max())
        rows.append({"nh": n, "h_rel": n_f / n, "n_elements": disc.n_elements, "time_s": round(sol.time_s, 3),
                     "kkt_worst": sol.kkt.worst, "U": sol.U, "e_sigma_energy": e_sigma, "e_strain_L2": e_strain,
                     "e_u_max": e_u_max, "e_U": abs(sol.U - sf.U) / abs(sf.U),
                     "nested_violation": t["nested_violation"],
                     "plastic_volume_fraction": summary(disc, sol)["plastic_volume_fraction"]})
    h = [r["h_rel"] for r in rows]
    rates = {k: fit_rate(h, [r[k] for r in rows]) for k in ("e_sigma_energy", "e_strain_L2", "e_u_max", "e_U")}
    return {"problem": {"L": L, "grading": grading, "force": force, "yield_stress": yield_stress,
                        "hardening": hardening, "R": R, "E": E, "nu": NU},
            "finest": {"nh": n_f, "n_elements": fine.n_elements, "kkt_worst": sf.kkt.worst, "U": sf.U,
                       "time_s": round(sf.time_s, 3)},
            "levels": rows, "rates": rates, "theorem_2_rate": 0.5}


# ----------------------------------------------------------------------------
# 4. Load-displacement
# ----------------------------------------------------------------------------


def load_displacement(forces: Sequence[float], *, L: float = 10.0, nh: int = 48, grading: float = 1.5,
                      yield_stress: float = SY_CYLINDER, hardening: float = 1e4) -> dict[str, Any]:
    """U(F), contact half-width, peak pressure and plastic zone of the cylinder problem, next to
    the elastic solution on the same mesh and the Hertz half-width."""
    rows = []
    for F in forces:
        row = {"F": float(F), "hertz_b": ref.hertz_cylinder(F, R, E, NU)["b"]}
        for tag, sy in (("plastic", yield_stress), ("elastic", ELASTIC)):
            disc = ep.discretize(cylinder_problem(L, nh, grading, F, yield_stress=sy, hardening=hardening,
                                                  contact_radius=4.0))
            sol = solve(disc, "conic")
            s = summary(disc, sol)
            row[tag] = {"U": sol.U, "contact_radius": s["contact_radius"], "max_contact_pressure": s["max_contact_pressure"],
                        "plastic_volume_fraction": s["plastic_volume_fraction"], "kkt_worst": sol.kkt.worst,
                        "max_von_mises": s["max_von_mises"], "time_s": round(sol.time_s, 3),
                        "contact_zone_edge_active": bool(sol.active[np.argmax(disc.contact_radii())]),
                        **({"zone": plastic_zone(disc, sol)} if tag == "plastic" else {})}
        rows.append(row)
    return {"problem": {"L": L, "nh": nh, "grading": grading, "yield_stress": yield_stress, "hardening": hardening,
                        "R": R, "E": E, "nu": NU, "n_elements": 4 * nh * nh},
            "points": rows}


# ----------------------------------------------------------------------------
# 5. Perfect plasticity: flat punch
# ----------------------------------------------------------------------------


def limit_load(disc: ep.Discretization) -> dict[str, Any]:
    """Largest F for which (S) is feasible: maximise F subject to the constraints of (S).

    The stresses are ``sigma_y`` times the unknowns and volumes are relative, so the numbers
    are O(1); Clarabel solves the SOCP ``max F : sum |T| B^T tau = N^T lam, sum lam = F,
    lam >= 0, sqrt(3/2)|dev tau_T| <= sigma_y``.
    """
    import clarabel

    from elastoplast.fem.stress_form import deviatoric_basis

    n, k, nc = disc.n_elements, disc.k, disc.n_contact
    sy = disc.material.yield_stress
    L = disc.length_scale
    vol = disc.volumes / L**disc.dim
    Bs = (disc.B * L).tocsr()
    n_cols = n * k + nc + 1
    F_col = n * k + nc
    BtV = (Bs.T @ sp.diags(np.repeat(vol, k))).tocsc()
    A_eq = sp.hstack([BtV, -disc.N.T, sp.csc_matrix((disc.n_free, 1))])
    A_force = sp.hstack([sp.csc_matrix((1, n * k)), sp.csc_matrix(np.ones((1, nc))), sp.csc_matrix([[-1.0]])])
    A_sign = sp.hstack([sp.csc_matrix((nc, n * k)), -sp.eye(nc), sp.csc_matrix((nc, 1))])
    Q = deviatoric_basis(k)
    block = sp.vstack([sp.csr_matrix((1, k)), sp.csr_matrix(-math.sqrt(1.5) * Q.T)])  # (k, k)
    A_soc = sp.hstack([sp.kron(sp.eye(n), block), sp.csc_matrix((n * k, nc + 1))])
    A = sp.vstack([A_eq, A_force, A_sign, A_soc], format="csc")
    b = np.concatenate([np.zeros(disc.n_free + 1), np.zeros(nc), np.tile(np.r_[1.0, np.zeros(k - 1)], n)])
    q = np.zeros(n_cols)
    q[F_col] = -1.0
    cones = [clarabel.ZeroConeT(disc.n_free + 1), clarabel.NonnegativeConeT(nc)] + [clarabel.SecondOrderConeT(k)] * n
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-10
    t0 = time.perf_counter()
    res = clarabel.DefaultSolver(sp.csc_matrix((n_cols, n_cols)), q, A, b, cones, settings).solve()
    F = float(res.x[F_col]) * sy * L ** (disc.dim - 1)
    return {"F_limit": F, "status": str(res.status).split(".")[-1], "iterations": int(res.iterations),
            "time_s": round(time.perf_counter() - t0, 3)}


def punch_study(nh: Sequence[int], *, L: float = 4.0, h_levels: Sequence[float] = (1e-1, 1e-2, 1e-3, 1e-4),
                h_nh: int | None = None, yield_stress: float = 1000.0) -> dict[str, Any]:
    """Limit pressure of a flat punch (half-width 1) against Prandtl; then H -> 0."""
    w = 1.0
    p_prandtl = ref.prandtl_pressure(yield_stress)
    rows = []
    for n in nh:
        disc = ep.discretize(punch_problem(L, n, 1.0, yield_stress=yield_stress))
        lim = limit_load(disc)
        p = lim["F_limit"] / (2 * w)
        # the stress form (S) itself, either side of the computed limit
        check = {}
        for name, factor in (("below", 0.99), ("above", 1.01)):
            s = ep.solve(disc.with_force(factor * lim["F_limit"]), "conic")
            check[name] = {"status": s.status.value, "kkt_worst": s.kkt.worst}
        rows.append({"nh": n, "h_over_w": L / n, "n_elements": disc.n_elements, **lim, "p_limit": p,
                     "p_over_prandtl": p / p_prandtl, "S_check": check})
    # the built-in two-triangle split locks: (S) stays feasible far above Prandtl
    n_g = nh[min(1, len(nh) - 1)]
    kuhn = ep.discretize(punch_problem(L, n_g, 1.0, yield_stress=yield_stress, crossed=False))
    lim_kuhn = limit_load(kuhn)
    # ep.solve refuses H = 0 on this locking mesh (checks.check_perfect_plasticity, citing
    # this very measurement); the conic solver is called below the registry to show why
    from elastoplast.solvers.conic import solve_conic

    far = solve_conic(kuhn.with_force(3.0 * 2 * w * p_prandtl))
    generator_mesh = {"nh": n_g, "limit_program_status": lim_kuhn["status"],
                      "S_at_3x_prandtl": {"status": far.status.value, "kkt_worst": far.kkt.worst, "U": far.U,
                                          "plastic_element_share": float(far.plastic.mean())}}
    # H -> 0 on one mesh: below the limit load the solutions converge to the H = 0 one;
    # above it U grows without bound.
    n_h = h_nh or nh[min(1, len(nh) - 1)]
    disc0 = ep.discretize(punch_problem(L, n_h, 1.0, yield_stress=yield_stress))
    F_lim = limit_load(disc0)["F_limit"]
    series = []
    for share in (0.9, 1.1):
        F = share * F_lim
        perfect = ep.solve(ep.discretize(punch_problem(L, n_h, F, yield_stress=yield_stress)), "conic")
        rows_h = []
        for H_rel in list(h_levels):
            disc = ep.discretize(punch_problem(L, n_h, F, yield_stress=yield_stress, hardening=H_rel * E))
            sol = solve(disc, "conic")
            row = {"H_over_E": H_rel, "U": sol.U, "kkt_worst": sol.kkt.worst,
                   "plastic_volume_fraction": summary(disc, sol)["plastic_volume_fraction"],
                   "max_xi_over_sy": float(sol.xi.max() / yield_stress)}
            if perfect.status is Status.CONVERGED:
                diff = energy_norm_sq(disc0, sol.sigma - perfect.sigma, np.zeros(disc.n_elements))
                row["sigma_diff_to_H0"] = math.sqrt(diff / energy_norm_sq(disc0, perfect.sigma, np.zeros(disc.n_elements)))
            rows_h.append(row)
        series.append({"F_over_limit": share, "F": F, "H0_status": perfect.status.value,
                       "H0_U": perfect.U if perfect.status is Status.CONVERGED else None,
                       "H0_kkt_worst": perfect.kkt.worst if perfect.status is Status.CONVERGED else None,
                       "hardening_sweep": rows_h})
    return {"reference": {"formula": "Prandtl: p = (2 + pi) sigma_y / sqrt(3) (docs/validation.md)", "sigma_y": yield_stress,
                          "p_prandtl": p_prandtl, "half_width": w},
            "problem": {"L": L, "E": E, "nu": NU, "mesh": "uniform criss-cross (4 triangles per square)"},
            "mesh_sequence": rows, "generator_mesh": generator_mesh,
            "extrapolated_p_over_prandtl": extrapolate_linear_in_h(rows), "H_to_zero": {"nh": n_h, "F_limit": F_lim, "series": series}}


def extrapolate_linear_in_h(rows: list[dict]) -> float:
    """``p(h) = p_0 + c h`` through the two finest meshes (the measured error halves with h)."""
    if len(rows) < 2:
        return float("nan")
    r1, r2 = rows[-2], rows[-1]
    h1, h2 = r1["h_over_w"], r2["h_over_w"]
    return float((h1 * r2["p_over_prandtl"] - h2 * r1["p_over_prandtl"]) / (h1 - h2))
