# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Uzawa's method: how many iterations, and why
#
# Uzawa's method (end of Section 2 of the paper; `docs/methods.md`) is a projected
# gradient method with step ρ. It converges for 0 < ρ < 2/λ_max(C); its rate depends on
# the step, on how much of the body is plastic (the hardening modulus H) and, ideally,
# not on the mesh. We measure the iteration count to a fixed KKT tolerance on the 2D
# cylinder problem (`problems/cylinder_2d.toml`: plane strain, a rigid cylinder pressed
# into a clamped block) against each of the three.
#
# Set `ELASTOPLAST_NOTEBOOK_SMALL=1` for coarse meshes (too coarse to show the trends:
# the figures quoted below are from the full size).

# %%
import os

import matplotlib.pyplot as plt

import elastoplast as ep

SMALL = os.environ.get("ELASTOPLAST_NOTEBOOK_SMALL") == "1"
NH = 6 if SMALL else 20          # the block is 2 NH x NH squares
TOL = 1e-5                       # every relative KKT residual below this
# the certificate at every iteration, so the counts are exact (by default Uzawa checks
# every few iterations, an interval chosen from measured timings)
UZAWA = {"tol": TOL, "check_every": 1}
HAS_UZAWA = "uzawa" in ep.METHODS


def cylinder(nh, hardening=1e4, yield_stress=1200.0, force=4315.0):
    return ep.discretize(ep.problem_from_dict({
        "mesh": {"generator": "rectangle", "size": [20.0, 10.0], "divisions": [2 * nh, nh],
                 "grading": 1.5, "contact_radius": 4.0},
        "material": {"E": 2e5, "nu": 0.3, "yield_stress": yield_stress, "hardening": hardening},
        "obstacle": {"shape": "cylinder", "radius": 40.0},
        "load": {"force": force},
    }))


disc = cylinder(NH)
bound = 2.0 / disc.material.max_stiffness_eigenvalue()
print(f"{disc.n_elements} triangles; step bound 2/lambda_max(C) = {bound:.3e} 1/MPa; Uzawa available: {HAS_UZAWA}")

# %% [markdown]
# ## The step ρ
# Iterations to the tolerance for steps from 10% to 95% of the bound, elastic
# (σ_y huge) and elasto-plastic. The residual history of each run is in `sol.history`.

# %%
shares = [0.1, 0.25, 0.5, 0.75, 0.95] if not SMALL else [0.25, 0.5, 0.95]
counts = {}
if HAS_UZAWA:
    for label, sy in (("elastic", 1e12), ("plastic", 1200.0)):
        d = cylinder(NH, yield_stress=sy)
        counts[label] = [ep.solve(d, "uzawa", rho=s * bound, **UZAWA).iterations for s in shares]
        print(f"{label}: iterations {counts[label]} at rho / bound = {shares}")
    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    for label, its in counts.items():
        ax.plot(shares, its, "o-", label=label)
    ax.set_xlabel("rho / (2 / lambda_max(C))")
    ax.set_ylabel(f"iterations to KKT <= {TOL:g}")
    ax.set_yscale("log")
    ax.legend()
    plt.show()

# %% [markdown]
# ## The residual history
# The certificate's worst residual along the iterations for one run: a slow linear rate,
# which is why the method stops on the residuals and never on the step length.

# %%
if HAS_UZAWA:
    sol = ep.solve(disc, "uzawa", **UZAWA)
    it = [h["iteration"] for h in sol.history]
    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    ax.semilogy(it, [h["kkt_worst"] for h in sol.history], "-")
    ax.set_xlabel("iteration")
    ax.set_ylabel("worst relative KKT residual")
    plt.show()
    print(f"{sol.status.value} after {sol.iterations} iterations, {sol.time_s:.2f} s")

# %% [markdown]
# ## Hardening
# With less hardening the return mapping flattens more of the stress field and the
# iteration count grows as H decreases, until the plastic zone stops changing: at this
# load (full size) from 17 iterations at H = 100 GPa to 27 at 3 GPa, then flat, the
# plastic zone growing only from 72 to 76 elements. Larger plastic zones need far more
# iterations (about 2,000 at six times this load with H = E/1000,
# `benchmarks/methods/README.md`).

# %%
H_values = [1e5, 1e4, 1e3] if SMALL else [1e5, 3e4, 1e4, 3e3, 1e3]
if HAS_UZAWA:
    its = []
    for H in H_values:
        its.append(ep.solve(cylinder(NH, hardening=H), "uzawa", **UZAWA).iterations)
    print(f"iterations {its} at H = {H_values} MPa")
    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    ax.loglog(H_values, its, "o-")
    ax.set_xlabel("hardening modulus H (MPa)")
    ax.set_ylabel("iterations")
    plt.show()

# %% [markdown]
# ## Mesh size
# The metric G of step (ii) is the squared L² norm of the strain, |ε(v)|², the same
# quantity the stresses are measured against, so the iteration count should not grow
# with refinement (`benchmarks/uzawa/REPORT.md`: 33 to 39 iterations from 1,600 to
# 25,600 triangles, 15 to 27 from 3,000 to 52,728 tetrahedra).

# %%
nh_values = [4, 6, 8] if SMALL else [10, 20, 40]
if HAS_UZAWA:
    rows = []
    for nh in nh_values:
        d = cylinder(nh)
        s = ep.solve(d, "uzawa", **UZAWA)
        rows.append((d.n_elements, s.iterations, s.time_s))
    print("triangles, iterations:", [(r[0], r[1]) for r in rows])
    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    ax.semilogx([r[0] for r in rows], [r[1] for r in rows], "o-")
    ax.set_xlabel("triangles")
    ax.set_ylabel("iterations")
    ax.set_ylim(bottom=0)
    plt.show()
