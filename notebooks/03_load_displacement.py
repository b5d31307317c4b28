# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Load–displacement: from first contact to a wide plastic zone
#
# A rigid cylinder (R = 40 mm) pressed into a steel block in plane strain
# (σ_y = 1200 MPa, H = 10 GPa). Hencky's law is path independent, so each force is an
# independent problem: we solve a sweep of forces and follow the rigid body's
# displacement U, the contact half-width, the peak pressure and the plastic zone, next
# to the elastic solution and Hertz's half-width.
#
# Set `ELASTOPLAST_NOTEBOOK_SMALL=1` for a coarse mesh and fewer forces.

# %%
import os

import matplotlib.pyplot as plt
import numpy as np

import elastoplast as ep

SMALL = os.environ.get("ELASTOPLAST_NOTEBOOK_SMALL") == "1"
NH = 10 if SMALL else 40
E, NU, R, SY = 2e5, 0.3, 40.0, 1200.0
E_star = E / (1 - NU**2)
# first yield by Green's fit (docs/validation.md): p0 = 1.795 sigma_y, F = pi R p0^2 / E*
F_yield = np.pi * R * ((1.164 + 2.975 * NU - 2.906 * NU**2) * SY) ** 2 / E_star
forces = F_yield * np.geomspace(0.2, 8.0, 5 if SMALL else 14)


def disc_at(force, yield_stress):
    return ep.discretize(ep.problem_from_dict({
        "mesh": {"generator": "rectangle", "size": [20.0, 10.0], "divisions": [2 * NH, NH],
                 "grading": 1.5, "contact_radius": 4.0},
        "material": {"E": E, "nu": NU, "yield_stress": yield_stress, "hardening": 1e4},
        "obstacle": {"shape": "cylinder", "radius": R},
        "load": {"force": float(force)},
    }))


# %% [markdown]
# ## The sweep
# The conic reference at every force, elasto-plastic and elastic (σ_y huge). Every
# solution is certified; the worst residual over the sweep is printed once.

# %%
rows, last = [], None
for F in forces:
    d = disc_at(F, SY)
    s = ep.solve(d, "conic")
    e = ep.solve(disc_at(F, 1e12), "conic")
    c = d.mesh.points[d.mesh.cells].mean(axis=1)
    rows.append({"F": F, "U": s.U, "U_el": e.U, "b": ep.summary(d, s)["contact_radius"],
                 "b_el": ep.summary(d, e)["contact_radius"], "p": ep.summary(d, s)["max_contact_pressure"],
                 "depth": c[s.plastic, 1].max(initial=0.0), "width": np.abs(c[s.plastic, 0]).max(initial=0.0),
                 "kkt": max(s.kkt.worst, e.kkt.worst)})
    last = (d, s)
print(f"{len(rows)} forces from {forces[0]:.0f} to {forces[-1]:.0f} N/mm on {last[0].n_elements} triangles; "
      f"worst KKT residual {max(r['kkt'] for r in rows):.1e}")

# %%
F = np.array([r["F"] for r in rows])
fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
ax[0].plot(F, [r["U"] for r in rows], "o-", label="elasto-plastic")
ax[0].plot(F, [r["U_el"] for r in rows], "s--", label="elastic")
ax[0].axvline(F_yield, c="k", ls=":", lw=0.8, label="first yield (Green)")
ax[0].set_xlabel("F (N/mm)")
ax[0].set_ylabel("U (mm)")
ax[0].legend()
ax[1].plot(F, [r["b"] for r in rows], "o-", label="contact half-width")
ax[1].plot(F, [r["b_el"] for r in rows], "s--", label="contact half-width, elastic")
ax[1].plot(F, np.sqrt(4 * F * R / (np.pi * E_star)), "k:", label="Hertz b")
ax[1].plot(F, [r["depth"] for r in rows], "^-", label="plastic zone depth")
ax[1].plot(F, [r["width"] for r in rows], "v-", label="plastic zone half-width")
ax[1].axvline(F_yield, c="k", ls=":", lw=0.8)
ax[1].set_xlabel("F (N/mm)")
ax[1].set_ylabel("mm")
ax[1].legend(fontsize=8)
plt.show()

# %% [markdown]
# ## The plastic zone at the largest force
# Von Mises stress near the contact; the plastic elements are outlined. At this force the
# zone has reached the surface and spreads sideways, and it reaches deep into the 10 mm
# block (about 8.8 mm at full size): the clamped top now matters, and a study of the
# half-space would need a larger block. The contact zone must also stay inside the
# declared Γ0 (here |x| ≤ 4 mm): if its outermost node is active, Γ0 cuts the contact
# short. On the coarse mesh of small mode it does; at full size it does not.

# %%
d, s = last
r = d.contact_radii()
print(f"plastic zone depth {rows[-1]['depth']:.2f} mm; outermost node of Gamma_0 (r = {r.max():.2f} mm) "
      f"active: {bool(s.active[np.argmax(r)])}")
pts = d.mesh.points
fig, ax = plt.subplots(figsize=(7, 3.5))
tpc = ax.tripcolor(pts[:, 0], pts[:, 1], d.mesh.cells, facecolors=ep.von_mises(s.sigma), cmap="viridis")
ax.triplot(pts[:, 0], pts[:, 1], d.mesh.cells[s.plastic], color="r", lw=0.4)
ax.set_xlim(-6, 6)
ax.set_ylim(0, 6)
ax.set_aspect("equal")
ax.set_xlabel("x (mm)")
ax.set_ylabel("depth (mm)")
fig.colorbar(tpc, ax=ax, label="von Mises (MPa)")
plt.show()
