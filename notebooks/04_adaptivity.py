# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Adaptive refinement driven by the certified gap
#
# `elastoplast bounds` brackets the exact energy Π* of the continuous problem between
# −J of an equilibrium stress field and Π of the P1 solution (docs/bounds.md). The gap
# between the two is a sum of non-negative terms, one per element and one per contact
# facet: in total a proof, in its parts an error indicator. `elastoplast adapt` refines
# where those terms are large:
#
#     solve → bound → mark (Dörfler, θ) → refine (conforming bisection)
#
# until the relative gap (upper − lower)/|upper| is at most `rtol`, or a budget of
# elements or time is spent. Here: the 2D cylinder against uniform refinement, where
# the elements go, and the 3D quarter sphere. The recorded figures at full size are in
# `benchmarks/adapt/REPORT.md`.
#
# Set `ELASTOPLAST_NOTEBOOK_SMALL=1` for a coarser start and a looser target (the tests
# do).

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt

import elastoplast as ep

SMALL = os.environ.get("ELASTOPLAST_NOTEBOOK_SMALL") == "1"
PROBLEMS = Path(ep.__file__).resolve().parents[1] / "problems"

# %% [markdown]
# ## The 2D cylinder
# `problems/cylinder_2d.toml` (plane strain, R = 40 mm, F = 4315 N/mm, contact half-width
# about 1 mm in a 40 × 20 mm block), started from a coarse graded mesh of 20 × 10
# divisions. Each line: elements, the two bounds, the relative gap; the U bracket is
# computed on the final mesh (two more lower-bound programs, at F ∓ δ). Dörfler's θ = 0.5
# is raised wherever it would grow the mesh by less than `min_growth` = 1.5 times (each
# mesh costs a lower-bound program, so small steps waste the budget).

# %%
data = ep.read_toml(PROBLEMS / "cylinder_2d.toml")
data["mesh"]["divisions"] = [10, 5] if SMALL else [20, 10]
cylinder = ep.problem_from_dict(data)
options = ep.AdaptOptions(rtol=3e-2 if SMALL else 2e-3, theta=0.5)
run = ep.solve_adaptive(cylinder, options, report=lambda s: print(s.line()))
print(run.reason)

# %% [markdown]
# Uniform refinement of the same starting mesh (every triangle cut into four) up to the
# same number of elements, for comparison. Both gaps fall like a power of the number of
# elements N; the fitted exponents p (gap ~ N^-p) are in the legend. Both approach
# p = 1 = 2/d, the rate of P1 elements for the squared energy error that the gap bounds:
# adaptivity wins by a constant factor (about 3 in `benchmarks/adapt/`), because the
# problem file's mesh is already graded towards the contact and uniform refinement keeps
# that grading. Against an ungraded mesh the factor is about 19 (`benchmarks/adapt/grading.md`).

# %%
uni = ep.solve_uniform(cylinder, options, max_elements=run.final.n_elements)
gap_u = uni.final.gap_rel
n_a = ep.elements_at_gap(run.steps, gap_u)
print(f"uniform: {uni.final.n_elements:,} triangles for a gap of {gap_u:.2e}; adaptive reaches it with "
      f"{n_a:,.0f} ({uni.final.n_elements / n_a:.1f}x fewer)")
fig, ax = plt.subplots(figsize=(6, 4))
ep.plot_gap_curves(ax, {"adaptive, θ = 0.5, growth ≥ 1.5": run.steps, "uniform": uni.steps})
ax.set_title("2D cylinder: certified relative gap")
plt.show()

# %% [markdown]
# ## Where the elements go
# The final mesh coloured by the marking indicator (each element's gap term, plus the
# terms of the contact facets it owns), with the plastic zone outlined in black and the
# active contact in red, the contact edge marked by triangles. On the left the whole
# block, on the right the contact and plastic zones: the refinement concentrates at the
# contact edge and inside the plastic zone, and the indicator ends up nearly
# equidistributed over the elements.

# %%
disc, sol = run.disc, run.solution
eta = ep.element_indicators(disc, run.bounds)
fig, ax = plt.subplots(1, 2, figsize=(12, 4.2), layout="constrained")
coll = ep.draw_indicator(ax[0], disc, sol, eta, edges=not SMALL)
ep.draw_indicator(ax[1], disc, sol, eta, window=ep.zoom_window(disc, sol))
ax[1].legend(loc="upper right", fontsize=8)
fig.colorbar(coll, ax=ax, label="local gap")
plt.show()
f = run.final
print(f"{f.n_elements:,} triangles: energy in [{f.energy_lower:.6g}, {f.energy_upper:.6g}], "
      f"U in [{f.U_lower:.5g}, {f.U_upper:.5g}] mm (discrete U_h = {f.U:.5g})")

# %% [markdown]
# ## The 3D quarter sphere
# `problems/sphere_quarter_3d.toml` (the default problem on a quarter model), started
# from 4 × 4 × 4 graded divisions. The equilibrium-element lower bound is the expensive
# part in 3D (about a minute at 1,000 tetrahedra on two cores), so this runs only a
# few steps; `benchmarks/adapt/` records a ten-minute run. The section shows the
# symmetry plane y = 0: the tetrahedra cut by it, coloured by their indicator.

# %%
data3 = ep.read_toml(PROBLEMS / "sphere_quarter_3d.toml")
data3["mesh"]["divisions"] = [3, 3, 3] if SMALL else [4, 4, 4]
quarter = ep.problem_from_dict(data3)
run3 = ep.solve_adaptive(quarter, ep.AdaptOptions(rtol=1e-3, max_iter=2 if SMALL else 4, bracket="never"),
             report=lambda s: print(s.line()))
print(f"{run3.reason}; fitted exponent over the steps p = {ep.fitted_rate(run3.steps):.2f}")

# %%
d3, s3 = run3.disc, run3.solution
eta3 = ep.element_indicators(d3, run3.bounds)
fig, ax = plt.subplots(1, 2, figsize=(12, 4.6), layout="constrained")
coll = ep.draw_indicator(ax[0], d3, s3, eta3, axis=1, value=0.0)
ep.draw_indicator(ax[1], d3, s3, eta3, axis=1, value=0.0, window=ep.zoom_window(d3, s3, axis=1))
ax[0].set_title("section y = 0 (symmetry plane)")
ax[1].legend(loc="upper right", fontsize=8)
fig.colorbar(coll, ax=ax, label="local gap")
plt.show()
