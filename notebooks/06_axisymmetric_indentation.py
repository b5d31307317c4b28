# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Spherical indentation in the meridian plane
#
# A rigid sphere pressed into a body of revolution is a 2D problem: with
# `axisymmetric = true` in `[mesh]` the mesh is the meridian half-plane r = x ≥ 0 (the
# axis is x = 0, the contact plane y = 0), the element weights are 2π |T| r_T and the hoop
# strain is one more strain row (docs/axisymmetry.md). Every method, the certificate and
# loading paths work on it unchanged. Here:
#
# - a sweep from first yield to a fully plastic contact, E* a / (σ_y R) from about 1 to
#   about 100, each point a Hencky solve on a graded gmsh mesh (`generator = "graded"`)
#   sized to its own contact radius;
# - the plastic zone growing with the load;
# - the mean pressure p_m / σ_y against E* a / (σ_y R) beside the literature's bands:
#   Hertz, first yield at p0 = 1.6 σ_y (ν = 0.3), Johnson's expanding-cavity model,
#   Tabor's 2.8–3.0;
# - a nanoindentation cycle (load, unload; Prandtl–Reuss) and its Oliver–Pharr analysis.
#
# Set `ELASTOPLAST_NOTEBOOK_SMALL=1` for coarse meshes and fewer loads.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

import elastoplast as ep

SMALL = os.environ.get("ELASTOPLAST_NOTEBOOK_SMALL") == "1"
E, NU, SY, R = 2e5, 0.3, 200.0, 10.0     # MPa, mm: a soft metal, E* / sigma_y = 1100
E_star = E / (1 - NU**2)
REFINE = 8 if SMALL else 40               # elements across the contact radius


def problem(a_target, load, hardening):
    """A graded meridian block 20 contact radii wide and deep around the expected contact
    radius ``a_target``: element size a / REFINE on the contact zone, growing away from it."""
    W = 20.0 * a_target
    return ep.problem_from_dict({
        "mesh": {"generator": "graded", "axisymmetric": True, "size": [W, W], "contact_radius": 2.0 * a_target,
                 "h_contact": a_target / REFINE, "h_far": W / 8},
        "material": {"E": E, "nu": NU, "yield_stress": SY, "hardening": hardening},
        "obstacle": {"shape": "sphere", "radius": R},
        "load": load,
    })


def expected(x):
    """The contact radius of E* a / (sigma_y R) = x and a force that gives about it: Hertz's
    mean pressure 4 E* a / (3 pi R) below first yield, the expanding-cavity estimate
    (plus a third of sigma_y) beyond."""
    a = x * SY * R / E_star
    cavity = (2 / 3) * (1 + np.log(max(1.0, (E * a / (SY * R) + 4 * (1 - 2 * NU)) / (6 * (1 - NU))))) + 1 / 3
    return a, np.pi * a * a * min(4 * E_star * a / (3 * np.pi * R), cavity * SY)


def contact_radius(ind):
    """The midpoint of the bracket between the last active and the first free contact node."""
    return 0.5 * (ind["contact_radius_active"] + ind["contact_radius_free"])


# %% [markdown]
# ## The sweep: from first yield to fully plastic
# Two hardening moduli, H / E = 10⁻² and 10⁻³. Hencky's law is path independent, so each
# load is a problem of its own, solved by Newton and certified; each has its own mesh,
# scaled to its expected contact radius, so every point resolves its contact zone alike.

# %%
xs = [1.5, 3.0, 6.0, 12.0, 30.0, 80.0] if SMALL else list(np.geomspace(1.0, 100.0, 12))
hardenings = {"H/E = 1e-2": E / 100, "H/E = 1e-3": E / 1000}
sweep = {name: [] for name in hardenings}
for name, H in hardenings.items():
    for x in xs:
        a_t, F = expected(x)
        disc = ep.discretize(problem(a_t, {"force": float(F)}, H))
        sol = ep.solve(disc, "newton", progress=False)
        sweep[name].append((disc, sol, ep.indentation_summary(disc, sol, axisymmetric=True)))
for name, runs in sweep.items():
    worst = max(s.kkt.worst for _, s, _ in runs)
    print(f"{name}: {len(runs)} solves, {min(d.n_elements for d, _, _ in runs)}-"
          f"{max(d.n_elements for d, _, _ in runs)} triangles each, all converged: "
          f"{all(s.converged for _, s, _ in runs)}, worst KKT {worst:.1e}")

# %% [markdown]
# ## The plastic zone grows with the load
# The plastic elements (von Mises stress at σ_y + ξ) of three points of the sweep, in
# units of the contact radius a. Just past first yield the zone is a small core below the
# surface, at about half a contact radius deep (Hertz's maximum shear lies at 0.48 a); it
# grows, reaches the surface at the contact edge and then engulfs the contact: the
# fully plastic regime, where the expanding-cavity picture of a hemispherical core
# holds.

# %%
runs = sweep["H/E = 1e-2"]
picks = [int(np.argmin(np.abs(np.log(np.array(xs) / x)))) for x in (3.0, 12.0, 80.0)]
fig, axes = plt.subplots(1, 3, figsize=(12, 3.8), sharey=True)
for ax, i in zip(axes, picks):
    disc, sol, ind = runs[i]
    a = contact_radius(ind)
    p = disc.mesh.points / a
    ax.tripcolor(p[:, 0], p[:, 1], disc.mesh.cells, facecolors=sol.plastic.astype(float), cmap="Reds",
                 vmin=0, vmax=1.4, edgecolors="0.85", linewidth=0.2)
    ax.axvline(1.0, color="C0", ls="--", lw=1)
    ax.set_xlim(0, 4)
    ax.set_ylim(0, 4)
    ax.set_aspect("equal")
    ax.set_xlabel("r / a")
    ax.set_title(f"E* a/(σ_y R) = {E_star * a / (SY * R):.1f}, p_m = {ind['mean_contact_pressure'] / SY:.2f} σ_y")
axes[0].set_ylabel("depth / a")
plt.show()
for i in picks:
    disc, sol, ind = runs[i]
    a = contact_radius(ind)
    print(f"E* a/(sigma_y R) = {E_star * a / (SY * R):5.1f}: plastic zone depth {ind['plastic_zone_depth'] / a:.2f} a, "
          f"radius {ind['plastic_zone_radius'] / a:.2f} a, {int(sol.plastic.sum())} plastic elements")

# %% [markdown]
# ## The mean pressure against E* a / (σ_y R)
# Johnson's indentation map (*Contact Mechanics*, ch. 6; MATH.md section 13):
#
# - elastic (Hertz): p_m = 4 E* a / (3π R), i.e. p_m / σ_y = (4 / 3π) x with x = E* a / (σ_y R);
# - first yield where Hertz's peak pressure p0 = (3/2) p_m reaches 1.6 σ_y (ν = 0.3):
#   x = 0.8 π ≈ 2.5;
# - the expanding-cavity model: (c/a)³ = [E a / (σ_y R) + 4 (1 − 2ν)] / [6 (1 − ν)],
#   p̄ / σ_y = (2/3) [1 + ln (c/a)³], the mean pressure between p̄ and p̄ + 2σ_y/3
#   depending on the source (a band);
# - fully plastic from x ≈ 30–40 with p_m ≈ 2.8–3.0 σ_y (Tabor) for small hardening.
#
# The contact radius of each point is the bracket's midpoint; the error bars are p_m at its
# two ends (the contact edge lies between the last active and the first free node).

# %%
x_line = np.geomspace(0.8, 150, 200)
a_line = x_line * SY * R / E_star
cavity = (2 / 3) * (1 + np.log(np.maximum(1.0, (E * a_line / (SY * R) + 4 * (1 - 2 * NU)) / (6 * (1 - NU)))))
fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.2))
ax.plot(x_line, 4 * x_line / (3 * np.pi), "k:", label="Hertz, 4x / 3π")
ax.fill_between(x_line, cavity, cavity + 2 / 3, color="C2", alpha=0.2, label="expanding cavity (Johnson)")
ax.axhspan(2.8, 3.0, color="C3", alpha=0.2, label="Tabor 2.8-3.0")
ax.axvline(0.8 * np.pi, color="0.5", ls="--", lw=1, label="first yield, x = 0.8π")
for k, (name, rows) in enumerate(sweep.items()):
    x = np.array([E_star * contact_radius(ind) / (SY * R) for _, _, ind in rows])
    pm = np.array([ind["mean_contact_pressure"] for _, _, ind in rows]) / SY
    lo, hi = (np.array([ind["mean_contact_pressure_range"][j] for _, _, ind in rows]) / SY for j in (0, 1))
    ax.errorbar(x, pm, yerr=[pm - lo, hi - pm], fmt="o-", ms=4, color=f"C{k}", capsize=2, label=name)
    bx.plot(x, [ind["contact_depth_ratio"] for _, _, ind in rows], "o-", ms=4, color=f"C{k}", label=name)
ax.set_xscale("log")
ax.set_ylim(0, 4)
ax.set_xlabel("E* a / (σ_y R)")
ax.set_ylabel("p_m / σ_y")
ax.legend(fontsize=8, loc="upper left")
bx.axhline(0.5, color="k", ls=":", label="Hertz, c² = 1/2")
bx.axhline(1.4, color="C3", ls="--", label="fully plastic, c² ≈ 1.4 (Hill et al.)")
bx.set_xscale("log")
bx.set_xlabel("E* a / (σ_y R)")
bx.set_ylabel("c² = a² / (2 R U)")
bx.legend(fontsize=8)
plt.show()
for name, rows in sweep.items():
    x = [E_star * contact_radius(ind) / (SY * R) for _, _, ind in rows]
    yielded = [xi for xi, (_, sol, _) in zip(x, rows) if sol.plastic.any()]
    elastic = [xi for xi, (_, sol, _) in zip(x, rows) if not sol.plastic.any()]
    disc, sol, ind = rows[-1]
    print(f"{name}: no plastic element up to x = {max(elastic, default=float('nan')):.2f}, "
          f"plastic from x = {min(yielded, default=float('nan')):.2f}; at x = {x[-1]:.0f}, "
          f"p_m = {ind['mean_contact_pressure'] / SY:.2f} sigma_y, c^2 = {ind['contact_depth_ratio']:.2f}, "
          f"pile-up {ind['pile_up'] / (sol.U or 1):.3f} U")

# %% [markdown]
# What to read in it. Below x ≈ 2.5 the points lie on Hertz's line and no element is
# plastic; first yield comes where Hertz says: the last point without a plastic element
# and the first with one (printed above) bracket x = 0.8π. Beyond it the pressure leaves the line and climbs
# slowly, inside or near the expanding-cavity band. In the fully plastic range it reaches
# Tabor's band; with H / E = 10⁻³ it ends at or just above it, with H / E = 10⁻² well
# above it (on the full meshes about 3.1 and 3.9 σ_y at x ≈ 100): the hardening raises the flow
# stress under the indenter (σ_y + ξ with ξ growing with the plastic strain), whereas
# Tabor's 2.8–3.0 is for materials that barely harden (on the coarse meshes of the small
# mode the contact radius is known only to a few elements, and the two hardenings can
# land on the same node). c² stays below the fully
# plastic 1.4: axisymmetric P1 triangles lock under plastic incompressibility (MATH.md
# sections 13 and 14), which holds pile-up back and stiffens the fully plastic answer;
# the locking-free element is a separate issue. The figures are those of the discrete
# problem, certified; their distance from the continuum is the element's.

# %% [markdown]
# ## A nanoindentation cycle and Oliver–Pharr
# Experiments load and unload: Prandtl–Reuss' law along a path (`ep.solve_path`), one
# certified backward-Euler step per force, loaded to a fully plastic contact
# (E* a / (σ_y R) ≈ 30) and unloaded to 5% of the peak. `ep.path_summary` holds the
# Oliver–Pharr analysis of the first unloading (`"oliver_pharr"`): the power law
# F = α (h − h_f)^m fitted to the upper half of the unloading curve, the stiffness S at
# its top, the contact depth h_c = h_max − 0.75 F_max / S, the sphere's projected area at
# h_c, the hardness F_max / A and the reduced modulus E_r = √π S / (2 √A), to be set
# against E* (a rigid indenter).

# %%
a_t, F_max = expected(30.0)
shares = [0.25, 0.5, 0.75, 1.0, 0.9, 0.8, 0.65, 0.5, 0.3, 0.05] if SMALL else \
    [0.1, 0.2, 0.35, 0.5, 0.65, 0.8, 0.9, 1.0, 0.95, 0.9, 0.8, 0.7, 0.6, 0.5, 0.35, 0.2, 0.05]
path = [float(s * F_max) for s in shares]
disc = ep.discretize(problem(a_t, {"path": path}, E / 100))
result = ep.solve_path(disc, path, "newton", progress=False)
rec = ep.path_summary(disc, result)
op = rec["oliver_pharr"]
peak = result.steps[op["step_peak"] - 1]
ind_peak = ep.indentation_summary(disc, peak.solution, axisymmetric=True)
print(f"{disc.n_elements} triangles, {len(result.steps)} steps, {rec['message']}, worst KKT {rec['kkt_worst']:.1e}")
print(f"fit: m = {op['m']:.2f}, h_f = {op['h_f']:.4g} mm, S = {op['S']:.4g} N/mm, largest residual {op['fit_residual']:.1e}")
print(f"h_max = {op['h_max']:.4g} mm, h_c = {op['h_c']:.4g} mm, A = {op['A']:.4g} mm^2 "
      f"(pi a^2 at the peak: {np.pi * contact_radius(ind_peak) ** 2:.4g})")
print(f"hardness {op['hardness']:.0f} MPa = {op['hardness'] / SY:.2f} sigma_y; p_m at the peak "
      f"{ind_peak['mean_contact_pressure']:.0f} MPa")
print(f"E_r = {op['E_r']:.4g} MPa against E* = {op['E_star']:.4g} MPa: ratio {op['E_r'] / op['E_star']:.3f}")

# %%
h = np.array([0.0] + [s.U for s in result.steps])
F = np.array([0.0] + [s.force for s in result.steps])
fig, ax = plt.subplots(figsize=(6.4, 4.4))
ax.plot(h, F, "o-", ms=4, color="0.3", label="path (Prandtl–Reuss steps)")
hf = np.linspace(op["h_f"], op["h_max"], 50)
ax.plot(hf, op["alpha"] * (hf - op["h_f"]) ** op["m"], "-", color="C1", lw=2, alpha=0.7,
        label=f"fit α (h − h_f)^m, m = {op['m']:.2f}")
ax.plot([op["h_max"], op["h_max"] - op["F_max"] / op["S"]], [op["F_max"], 0.0], "--", color="C2",
        label=f"S = {op['S']:.4g} N/mm")
ax.axvline(op["h_c"], color="C0", ls=":", label=f"h_c = {op['h_c']:.3g} mm")
ax.set_xlabel("h = U (mm)")
ax.set_ylabel("F (N)")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# The hardness lies near the mean pressure at the peak, as it should when the projected
# area at h_c matches the contact area: the two differ by how far h_c = h_max − 0.75 F / S
# (Oliver–Pharr's elastic sink-in) is from the real contact depth, and with the
# P1 element's short pile-up the difference stays small here. E_r comes out above E*:
# the block is finite and clamped, 20 contact radii on each side, and the mesh is coarse
# far from the contact, both of which stiffen the unloading; on the same mesh the
# discretisation error of the unloading slope is that of an elastic solve. The path
# summary (`summary.json` of `elastoplast solve` on a path problem) holds the same
# figures, and `path.png` draws the fitted law.
