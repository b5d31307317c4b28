# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # A guided tour of elastoplast
#
# The paper's problem (C. Johnson, *An elasto-plastic contact problem*): a rigid sphere
# (R = 40 mm) is pressed with F = 7330 N into a steel block clamped on every face but the
# bottom. Hencky plasticity with von Mises yield (σ_y = 1500 MPa) and linear hardening
# (H = 10 GPa). We solve the quarter model (`problems/sphere_quarter_3d.toml`, symmetry
# planes x = 0 and y = 0, a quarter of the force) by the conic reference and by Uzawa's
# method, certify both, and look at the plastic zone, the contact pressure against Hertz
# and the deformed shape.
#
# Set `ELASTOPLAST_NOTEBOOK_SMALL=1` to run on a coarse mesh (that is what the tests do).

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import elastoplast as ep

SMALL = os.environ.get("ELASTOPLAST_NOTEBOOK_SMALL") == "1"
PROBLEMS = Path(ep.__file__).resolve().parents[1] / "problems"

# %% [markdown]
# ## The problem
# A problem is a TOML file (or the same structure as a dict). Here we read the file and,
# in small mode, coarsen the mesh.

# %%
data = ep.read_toml(PROBLEMS / "sphere_quarter_3d.toml")
if SMALL:
    data["mesh"]["divisions"] = [5, 5, 5]
problem = ep.problem_from_dict(data)
disc = ep.discretize(problem)
m = problem.material
print(f"{disc.n_elements} tetrahedra, {disc.n_contact} contact nodes; E = {m.E:g}, nu = {m.nu}, "
      f"sigma_y = {m.yield_stress:g}, H = {m.hardening:g}; the quarter carries F = {problem.force:g} N")

# %% [markdown]
# ## Two solvers, one certificate
# The conic reference solves the stress form (S) with an interior-point method and
# finishes with a few Newton steps; Uzawa's method alternates the return mapping and a
# projection onto the contact constraints. Both answers go through the same KKT check
# (`docs/certificate.md`).

# %%
methods = ["conic"] + (["uzawa"] if "uzawa" in ep.METHODS else [])
sols = {name: ep.solve(disc, name) for name in methods}
for name, sol in sols.items():
    s = ep.summary(disc, sol)
    print(f"{name:6s} {sol.status.value:10s} U = {sol.U:.6f} mm, worst KKT residual {sol.kkt.worst:.1e}, "
          f"{sol.iterations} iterations, {sol.time_s:.1f} s, plastic volume share {s['plastic_volume_fraction']:.4f}")
if len(sols) == 2:
    a, b = sols["conic"], sols["uzawa"]
    d = ep.energy_norm_sq(disc, a.sigma - b.sigma, a.xi - b.xi) / ep.energy_norm_sq(disc, a.sigma, a.xi)
    print(f"conic vs Uzawa: stresses differ by {np.sqrt(d):.1e} in the energy norm, U by {abs(a.U - b.U) / a.U:.1e}")
sol = sols["conic"]

# %% [markdown]
# ## The plastic zone
# A slice through the symmetry plane y = 0: the elements with a face on it, coloured by
# their von Mises stress; the plastic ones are outlined. Plasticity starts below the
# surface, as Hertz theory predicts (first yield at z ≈ 0.48 a for ν = 0.3).

# %%
pts, cells = disc.mesh.points, disc.mesh.cells
on_plane = np.abs(pts[cells][:, :, 1]) < 1e-12
faces = on_plane.sum(axis=1) == 3
tri = np.array([c[o] for c, o in zip(cells[faces], on_plane[faces])])
vm = ep.von_mises(sol.sigma)[faces]
fig, ax = plt.subplots(figsize=(7, 3.5))
tpc = ax.tripcolor(pts[:, 0], pts[:, 2], tri, facecolors=vm, cmap="viridis")
plastic = sol.plastic[faces]
ax.triplot(pts[:, 0], pts[:, 2], tri[plastic], color="r", lw=0.6)
ax.set_xlim(0, 3)
ax.set_ylim(0, 1.5)
ax.set_aspect("equal")
ax.set_xlabel("x (mm)")
ax.set_ylabel("depth z (mm)")
ax.set_title("von Mises (MPa) on y = 0; plastic elements in red")
fig.colorbar(tpc, ax=ax)
plt.show()

# %% [markdown]
# ## Contact pressure against Hertz
# The lumped nodal pressures of both solvers against the elastic Hertz distribution
# p0 sqrt(1 - r²/a²) for the full sphere's force. Plasticity flattens the peak and widens
# the contact.

# %%
E_star = m.E / (1 - m.nu**2)
R, F_full = problem.obstacle.radius, 4 * problem.force
a = (3 * F_full * R / (4 * E_star)) ** (1 / 3)
p0 = 3 * F_full / (2 * np.pi * a**2)
r = disc.contact_radii()
rr = np.linspace(0, a, 200)
fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(rr, p0 * np.sqrt(1 - (rr / a) ** 2), "k-", label="Hertz (elastic)")
for name, s in sols.items():
    ax.plot(r, s.contact_pressure, "o" if name == "conic" else "x", ms=4, label=name)
ax.set_xlim(0, 2 * a)
ax.set_xlabel("r (mm)")
ax.set_ylabel("contact pressure (MPa)")
ax.legend()
plt.show()

# %% [markdown]
# ## Deformed shape
# The bottom surface along the x axis (y = 0) after loading, against the rigid sphere's
# surface at its final position x_d = U − ψ(x). The gap is zero where they touch.

# %%
bottom = np.flatnonzero((np.abs(pts[:, 2]) < 1e-12) & (np.abs(pts[:, 1]) < 1e-12))
bottom = bottom[np.argsort(pts[bottom, 0])]
x = pts[bottom, 0]
fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(x, sol.u[bottom, 2] * 1e3, "o-", ms=3, label="body surface u_z")
psi = R - np.sqrt(R**2 - x**2)
ax.plot(x, (sol.U - psi) * 1e3, "k--", label="sphere surface U - psi")
ax.set_xlim(0, 3)
ax.set_xlabel("x (mm)")
ax.set_ylabel("vertical position (µm)")
ax.legend()
plt.show()
