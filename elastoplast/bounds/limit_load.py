"""Limit load with perfect plasticity (H = 0): the kinematic upper bound (docs/bounds.md).

Upper bound theorem. For a unit velocity of the rigid body (V = 1) and any
velocity field v with v = 0 where displacements are fixed, ``v_d >= 1`` on the
contact zone Γ0 and ``tr eps(v) = 0``, every statically and plastically
admissible stress field at load F satisfies

    F = ∫_Γ0 λ V <= ∫_Γ0 λ v_d = ∫_Ω σ : ε(v) <= ∫_Ω D(ε(v)),

so ``F_c <= ∫ D(ε(v))``, with the von Mises dissipation
``D(ε) = sup_{σ in D} σ : ε = σ_y sqrt(2/3) |ε|`` for ``tr ε = 0`` (Mandel
vectors: ``|ε|`` is the Frobenius norm). In plane strain ``ε33 = 0``, so
``tr ε = ε11 + ε22 = 0`` and ``|ε|^2 = 2 ε11^2 + 2 ε12^2``:
``D = 2 k sqrt(ε11^2 + ε12^2)`` with ``k = σ_y / sqrt 3``.

Two velocity spaces (``LimitOptions.order``):

* P1: ε is constant per element, the integral is exact, v_d is linear on a
  facet so ``v_d >= 1`` at the contact nodes is ``v_d >= 1`` on Γ0. P1 triangles
  lock under incompressibility unless the crossed pattern is used; P1
  tetrahedra lock on practically any mesh.
* P2: ε is linear per element; ``tr ε = 0`` at the d + 1 vertices makes it
  zero everywhere, and by convexity of D, ``∫_T D(ε) <= |T|/(d+1) Σ_i D(ε_i)``.
  On a contact facet v_d is quadratic; in Bernstein form it is a convex
  combination of its Bernstein coefficients (the vertex values and
  ``2 v(mid_ij) - (v_i + v_j)/2`` per edge), so those coefficients ``>= 1``
  give ``v_d >= 1`` everywhere on the facet.

The conic program is assembled for Clarabel directly. The interior point
satisfies ``tr ε = 0`` only to its tolerance, so the answer is repaired before
it is used as a bound: v is projected onto the kernel of the trace rows (to
round-off; the residual is reported), and then

    F_upper = Σ_p w_p σ_y sqrt(2/3) |ε_p(v)| / min_Γ0 v_d,

with ``min_Γ0 v_d`` the smallest contact row (nodal value or Bernstein
coefficient). The lower bound comes from the equilibrium element
(``elastoplast.bounds.lower.static_limit_load``) when it is available.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from elastoplast.bounds.lower import LimitLowerBound, LowerBoundOptions, check_lower_bound_size
from elastoplast.bounds.equilibrium.bound import static_limit_load
from elastoplast.certificate.solution import Status
from elastoplast.errors import InputError, expect
from elastoplast.fem.axisymmetry import check_not_axisymmetric
from elastoplast.fem.discretize import Discretization, check_hencky, free_strain_operator
from elastoplast.fem.assembly import element_geometry
from elastoplast.fem.material import identity_vector
from elastoplast.mesh.base import Mesh
from elastoplast.mesh.topology import element_edges, local_edges, locate_rows
from elastoplast.options import SolverOptions, option
from elastoplast.solvers.backends import clarabel_settings, solve_clarabel

SQRT_2_3 = np.sqrt(2.0 / 3.0)
#: the static program's time when the kinematic one spent the budget (Clarabel stops after an iteration)
MIN_LOWER_TIME = 1e-3


@dataclass(frozen=True)
class LimitOptions(SolverOptions):
    """Settings of the kinematic program (declared and checked like every
    solver's options, :mod:`elastoplast.options`).

    ``order``: velocity degree, 1 or 2 (default: 2, which does not lock in 3D
    and, measured on the Prandtl punch, gives tighter bounds in 2D as well; see
    benchmarks/bounds/limit.md). ``ip_tol``: Clarabel's gap and feasibility
    tolerance. ``tol``: the largest ``max|tr ε| / max|ε|`` accepted after
    the projection for the bound to count as certified."""

    order: int = option(2, int, "velocity degree (1: P1, 2: P2)", lo=1, hi=2)
    max_iter: int = option(400, int, "interior-point iteration limit", lo=1, hi=10_000)
    ip_tol: float = option(1e-9, float, "Clarabel's gap and feasibility tolerance", lo=1e-14, hi=1e-3)
    verbose: bool = option(False, bool, "Clarabel's own iteration log (on stdout)", persist=False)
    linear_solver: str = option("qdldl", str, "Clarabel's KKT factorisation", choices=("qdldl", "faer"))
    tol: float = option(1e-10, float, "largest relative trace residual of a certified bound", lo=1e-16, hi=1e-4)


# ----------------------------------------------------------------------------
# velocity spaces
# ----------------------------------------------------------------------------


@dataclass(frozen=True)
class VelocitySpace:
    """A conforming velocity space and where its dissipation is evaluated.

    Nodes are the mesh vertices, then (P2) the edge midpoints ``edges (n_edges,
    2)``; dofs ``node * d + component``, ``free`` those not fixed. ``B`` maps
    free dofs to Mandel strains at the dissipation points, rows ``point * k +
    component`` (one point per element for P1, its d + 1 vertices for P2, points
    of an element consecutive); ``weights`` are the matching quadrature
    weights (``|T|`` or ``|T| / (d+1)``). ``contact`` maps free dofs to values
    whose minimum bounds ``v_d`` on Γ0 from below.
    """

    order: int
    dim: int
    n_nodes: int
    edges: np.ndarray
    free: np.ndarray
    B: sp.csr_matrix
    weights: np.ndarray
    contact: sp.csr_matrix

    @property
    def n_free(self) -> int:
        return self.free.size

    @property
    def n_points(self) -> int:
        return self.weights.size

    @property
    def k(self) -> int:
        return self.B.shape[0] // self.n_points

    def trace_rows(self) -> sp.csr_matrix:
        """``tr ε`` at every dissipation point: ``(n_points, n_free)``."""
        m = sp.csr_matrix(identity_vector(self.dim)[None, :])
        return (sp.kron(sp.eye(self.n_points), m) @ self.B).tocsr()

    def strain(self, v_free: np.ndarray) -> np.ndarray:
        return (self.B @ v_free).reshape(self.n_points, self.k)

    def full_velocity(self, v_free: np.ndarray) -> np.ndarray:
        v = np.zeros(self.n_nodes * self.dim)
        v[self.free] = v_free
        return v.reshape(-1, self.dim)


def _facet_edges(edges: np.ndarray, facets: np.ndarray, n_vertices: int) -> np.ndarray:
    """Index in ``edges`` (unique sorted rows) of every edge of ``facets (m, d)``."""
    pairs = np.sort(facets[:, local_edges(facets.shape[1] - 1)].reshape(-1, 2), axis=1)
    idx = locate_rows(edges, pairs, n_vertices)
    if np.any(idx < 0):
        raise InputError("mesh", "a boundary facet of a named group is not a facet of the mesh")
    return idx


def _columns(position: np.ndarray, dofs: np.ndarray, field_name: str) -> np.ndarray:
    cols = position[dofs]
    if np.any(cols < 0):
        raise InputError(field_name, "a contact velocity is fixed by a clamped or symmetry group")
    return cols


def _strain_at_points(n_nodes: int, nodes: np.ndarray, grads: np.ndarray) -> sp.csr_matrix:
    """Mandel strains at points ``(n_pts * k, n_nodes * d)`` from the nodes
    ``(n_pts, nb)`` and basis gradients ``(n_pts, nb, d)`` at each point.

    :func:`~elastoplast.fem.discretize.free_strain_operator` (every dof free) builds the same rows for d + 1
    basis functions per row block; the nb functions are fed to it d + 1 at a time
    (padded with zero gradients) and the blocks summed.
    """
    n_pts, nb, d = grads.shape
    pad = -nb % (d + 1)
    nodes = np.concatenate([nodes, np.zeros((n_pts, pad), dtype=nodes.dtype)], axis=1)
    grads = np.concatenate([grads, np.zeros((n_pts, pad, d))], axis=1)
    blank = np.zeros((n_nodes, d))
    every = np.arange(n_nodes * d)
    B = sum(free_strain_operator(Mesh(points=blank, cells=nodes[:, c:c + d + 1]), grads[:, c:c + d + 1], every)
            for c in range(0, nb + pad, d + 1))
    B.sum_duplicates()
    B.eliminate_zeros()
    return B.tocsr()


def velocity_space(disc: Discretization, order: int) -> VelocitySpace:
    """P1 (the discretisation's own operators) or P2 velocities on ``disc``'s mesh."""
    mesh, d = disc.mesh, disc.dim
    if order == 1:
        return VelocitySpace(order=1, dim=d, n_nodes=mesh.n_nodes, edges=np.zeros((0, 2), dtype=np.int64),
                             free=disc.free, B=disc.B, weights=disc.volumes, contact=disc.N)
    if order != 2:
        raise InputError("limit.order", f"must be 1 or 2, got {order!r}")
    nv, cells = mesh.n_nodes, mesh.cells
    pairs = local_edges(d)
    edges, element_edge = element_edges(cells, nv)
    p2_cells = np.concatenate([cells, nv + element_edge], axis=1)

    # gradients of the P2 basis at vertex a: vertex i (4 delta_ia - 1) grad l_i,
    # edge (i, j) 4 (delta_ia grad l_j + delta_ja grad l_i)
    volumes, gl = element_geometry(mesh)
    n_el, nb = cells.shape[0], p2_cells.shape[1]
    G = np.zeros((n_el, d + 1, nb, d))
    for pt in range(d + 1):
        for i in range(d + 1):
            G[:, pt, i] = (3.0 if i == pt else -1.0) * gl[:, i]
        for e, (i, j) in enumerate(pairs):
            if i == pt:
                G[:, pt, d + 1 + e] = 4.0 * gl[:, j]
            elif j == pt:
                G[:, pt, d + 1 + e] = 4.0 * gl[:, i]
    n_nodes = nv + edges.shape[0]
    B_all = _strain_at_points(n_nodes, np.repeat(p2_cells, d + 1, axis=0), G.reshape(n_el * (d + 1), nb, d))

    fixed = np.zeros((n_nodes, d), dtype=bool)
    fixed[:nv] = np.isin(np.arange(nv * d), disc.fixed).reshape(nv, d)
    bnd = disc.problem.boundary
    fixed_groups = [(name, slice(None)) for name in bnd.clamped]
    fixed_groups += [(name, comp) for comp, names in bnd.fix_component.items() for name in names]
    for name, comp in fixed_groups:  # all the group's facets, as disc.fixed (FacetTopology.fixed skips interior ones)
        fixed[nv + _facet_edges(edges, mesh.groups[name], nv), comp] = True
    free = np.flatnonzero(~fixed.ravel())
    position = -np.ones(n_nodes * d, dtype=np.int64)
    position[free] = np.arange(free.size)

    # Bernstein coefficients of v_d on the contact facets
    cf = disc.facet_topology.contact_facets
    verts = np.unique(cf)
    rows = [np.arange(verts.size)]
    cols = [_columns(position, verts * d + d - 1, "boundary.contact")]
    vals = [np.ones(verts.size)]
    cedges = np.unique(_facet_edges(edges, cf, nv))
    ends = edges[cedges]
    r = verts.size + np.arange(cedges.size)
    for nodes, c in ((nv + cedges, 2.0), (ends[:, 0], -0.5), (ends[:, 1], -0.5)):
        rows.append(r)
        cols.append(_columns(position, nodes * d + d - 1, "boundary.contact"))
        vals.append(np.full(r.size, c))
    contact = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                            shape=(verts.size + cedges.size, free.size))
    return VelocitySpace(order=2, dim=d, n_nodes=n_nodes, edges=edges, free=free, B=B_all[:, free].tocsr(),
                         weights=np.repeat(volumes / (d + 1), d + 1), contact=contact)


# ----------------------------------------------------------------------------
# the conic program and its repair
# ----------------------------------------------------------------------------


def dissipation(yield_stress: float, eps: np.ndarray) -> np.ndarray:
    """Von Mises ``D(ε) = σ_y sqrt(2/3) |ε|`` per row of Mandel strains ``eps``
    (valid where ``tr ε = 0``; the trace is checked separately)."""
    return yield_stress * SQRT_2_3 * np.linalg.norm(eps, axis=-1)


def kinematic_program(space: VelocitySpace, length: float):
    """Clarabel data ``(P, q, A, b, cones)`` of

        minimise   sqrt(2/3) Σ_p w_p t_p            (σ_y = 1)
        subject to tr ε_p(v) = 0                   (zero cone, one row per point)
                   contact rows of v >= 1           (nonnegative cone)
                   |ε_p(v)| <= t_p                  (one second-order cone per point)

    in units where ``length`` (the mean element size) is 1: ``B`` is scaled by
    ``length`` and the weights by ``length**-d``, so the optimum is the bound
    in units of ``σ_y length**(d-1)``. Unknowns ``x = (v, t)``; in plane strain
    the cone leaves out ε33, which is zero. (Giving the cones their own strain
    variables, ``ε_p = B_p v`` as equality rows, was measured too: 1.3-1.6x
    faster in 3D but slower and only "almost solved" in 2D.)
    """
    import clarabel

    n, npt, d = space.n_free, space.n_points, space.dim
    comps = np.array([0, 1, 3]) if d == 2 else np.arange(6)  # plane strain: no eps33
    kk = comps.size
    Bs = (space.B * length).tocsr()
    n_cols = n + npt
    q = np.zeros(n_cols)
    q[n:] = SQRT_2_3 * space.weights / length**d
    A_tr = sp.hstack([space.trace_rows() * length, sp.csr_matrix((npt, npt))])
    A_c = sp.hstack([-space.contact, sp.csr_matrix((space.contact.shape[0], npt))])
    # cone p: rows p (1 + kk) <- t_p, p (1 + kk) + 1 + i <- eps_p[comps[i]]
    Bc = Bs.tocoo()
    pt, comp = np.divmod(Bc.row, space.k)
    where = -np.ones(space.k, dtype=np.int64)
    where[comps] = np.arange(kk)
    keep = where[comp] >= 0
    soc_rows = np.concatenate([pt[keep] * (1 + kk) + 1 + where[comp[keep]], np.arange(npt) * (1 + kk)])
    soc_cols = np.concatenate([Bc.col[keep], n + np.arange(npt)])
    soc_vals = -np.concatenate([Bc.data[keep], np.ones(npt)])
    A_soc = sp.csc_matrix((soc_vals, (soc_rows, soc_cols)), shape=(npt * (1 + kk), n_cols))
    A = sp.vstack([A_tr, A_c, A_soc], format="csc")
    b = np.concatenate([np.zeros(npt), -np.ones(space.contact.shape[0]), np.zeros(npt * (1 + kk))])
    cones = [clarabel.ZeroConeT(npt), clarabel.NonnegativeConeT(space.contact.shape[0])]
    cones += [clarabel.SecondOrderConeT(1 + kk)] * npt
    P = sp.csc_matrix((n_cols, n_cols))
    return P, q, A, b, cones


def project_trace_free(space: VelocitySpace, v: np.ndarray, sweeps: int = 4) -> np.ndarray:
    """The nearest ``v`` (Euclidean norm on the free dofs) with ``tr ε_p(v) = 0``.

    The correction is ``M^T y`` with ``M M^T y = M v`` (M: the trace rows). On
    the crossed pattern the trace rows are dependent and ``M M^T`` is singular,
    but ``M v`` lies in its range; a tiny shift ``M M^T + s I`` factored once
    and a few sweeps of iterative refinement (each on the current residual)
    converge to the minimum-norm correction, to round-off.
    """
    M = space.trace_rows()
    M = (M / max(abs(M).max(), np.finfo(float).tiny)).tocsr()
    K = (M @ M.T).tocsc()
    shift = 1e-12 * max(K.diagonal().max(initial=0.0), 1.0)
    solve = spla.splu((K + shift * sp.eye(K.shape[0])).tocsc()).solve
    for _ in range(sweeps):
        r = M @ v
        if not np.any(r):
            break
        v = v - M.T @ solve(r)
    return v


@dataclass(frozen=True)
class KinematicBound:
    """The kinematic upper bound ``F_upper >= F_c`` and the field that proves it.

    ``velocity (n_nodes, d)``: the repaired field scaled so that ``min_Γ0 v_d =
    1`` (P1 vertices, then the P2 edge midpoints of ``space.edges``);
    ``element_dissipation``: each element's (upper estimate of) ``∫_T D``, which
    sum to ``F_upper``; ``trace_residual``: ``max_p |tr ε_p| / max_p |ε_p|`` after
    the projection; ``solver_value``: Clarabel's optimum in user units (not a
    proof; ``F_upper`` is evaluated on the repaired field).
    """

    F_upper: float
    certified: bool
    order: int
    velocity: np.ndarray = field(repr=False)
    element_dissipation: np.ndarray = field(repr=False)
    trace_residual: float
    solver_value: float
    status: str
    iterations: int
    time_s: float
    message: str
    edges: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 2), dtype=np.int64))


def _check_perfectly_plastic(disc: Discretization) -> None:
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    if disc.material.hardening != 0:
        raise InputError("material.hardening",
                         f"the limit load needs perfect plasticity (hardening = 0), got {disc.material.hardening!r}: "
                         "with hardening every load has a solution")


def obstacle_note(disc: Discretization) -> str:
    """docs/bounds.md: for a curved obstacle the model's collapse load is not physical."""
    if disc.problem.obstacle.shape == "flat":
        return ""
    return (f"the obstacle is a {disc.problem.obstacle.shape}: psi drops out of the limit analysis, which "
            "returns the load that makes all of the declared contact zone a flat punch; it depends on the "
            "extent of the contact group and is not a physical limit load")


def evaluate_kinematic(disc: Discretization, space: VelocitySpace, v: np.ndarray) -> tuple[float, np.ndarray, float, float]:
    """``(F_upper, per-element dissipation, trace residual, min contact row)`` of
    any velocity ``v`` on the free dofs, scaled to ``min_Γ0 v_d = 1``."""
    eps = space.strain(v)
    D = dissipation(disc.material.yield_stress, eps) * space.weights
    per_element = D.reshape(disc.n_elements, -1).sum(axis=1)
    tr = eps[:, :3].sum(axis=1)
    residual = float(np.abs(tr).max(initial=0.0) / max(np.linalg.norm(eps, axis=1).max(initial=0.0), np.finfo(float).tiny))
    vmin = float((space.contact @ v).min())
    if not vmin > 0:
        return np.inf, per_element, residual, vmin
    return float(per_element.sum() / vmin), per_element / vmin, residual, vmin


def kinematic_limit_load(disc: Discretization, options: LimitOptions = LimitOptions()) -> KinematicBound:
    """The kinematic upper bound on the limit load (module docstring)."""
    _check_perfectly_plastic(disc)
    check_hencky(disc, "the limit load")
    check_not_axisymmetric(disc.problem, "the limit load")
    options = LimitOptions.of(options)
    t0 = time.perf_counter()
    space = velocity_space(disc, options.order)
    length = float(disc.volumes.mean() ** (1.0 / disc.dim))
    P, q, A, b, cones = kinematic_program(space, length)
    # QDLDL: on a 3D P2 quarter model (864 tetrahedra) faer took 55 s against 11 s
    settings = clarabel_settings(options, options.linear_solver)
    res = solve_clarabel(P, q, A, b, cones, settings)
    raw, status = res.raw, res.status
    v = project_trace_free(space, res.x[: space.n_free])
    F, per_el, residual, vmin = evaluate_kinematic(disc, space, v)
    notes = [res.label]
    if status is Status.INFEASIBLE:
        notes.append("no trace-free velocity lifts the contact zone (the mesh locks): no finite bound")
        F = np.inf
    elif not vmin > 0:
        notes.append(f"the smallest contact velocity is {vmin:.3g} <= 0: no finite bound")
    elif residual > options.tol:
        notes.append(f"trace residual {residual:.1e} above {options.tol:.0e}: not certified")
    certified = bool(np.isfinite(F) and residual <= options.tol)
    note = obstacle_note(disc)
    if note:
        notes.append(note)
    return KinematicBound(
        F_upper=float(F),
        certified=certified,
        order=space.order,
        velocity=space.full_velocity(v / vmin if vmin > 0 else v),
        element_dissipation=per_el,
        trace_residual=residual,
        solver_value=res.objective * disc.material.yield_stress * length ** (disc.dim - 1),
        status=raw,
        iterations=res.iterations,
        time_s=time.perf_counter() - t0,
        message="; ".join(notes),
        edges=space.edges,
    )


@dataclass(frozen=True)
class LimitBracket:
    """``F_lower <= F_c <= F_upper`` on one mesh; ``ratio = F_upper / F_lower``.

    ``upper``: the :class:`KinematicBound`; ``lower``: the
    :class:`~elastoplast.bounds.lower.LimitLowerBound` of the equilibrium element.
    ``certified`` holds only when both bounds are proofs; ``message`` adds, for a
    curved obstacle, that the load is not a physical limit load.
    """

    F_lower: float
    F_upper: float
    certified: bool
    upper: KinematicBound
    lower: LimitLowerBound
    message: str

    @property
    def ratio(self) -> float:
        return self.F_upper / self.F_lower if self.F_lower > 0 else np.inf

    def as_dict(self) -> dict:
        """A JSON-ready summary."""
        return {"F_lower": self.F_lower, "F_upper": self.F_upper, "ratio": self.ratio, "certified": self.certified,
                "lower_certified": bool(self.lower.certified), "upper_certified": self.upper.certified,
                "upper_order": self.upper.order, "upper_trace_residual": self.upper.trace_residual,
                "lower_time_s": float(self.lower.timings.get("total", np.nan)), "upper_time_s": self.upper.time_s,
                "message": self.message}


def limit_load(disc: Discretization, options: LimitOptions = LimitOptions(),
               lower_options: LowerBoundOptions = LowerBoundOptions()) -> LimitBracket:
    """``F_lower <= F_c <= F_upper`` from the static program of the equilibrium
    element (:func:`~elastoplast.bounds.lower.static_limit_load`) and the kinematic
    program (:func:`kinematic_limit_load`) on ``disc``'s mesh; ``disc.force`` is
    not used. ``options.time_limit`` is the whole bracket's budget: the static program
    gets what the kinematic one left (at least ``MIN_LOWER_TIME``), unless
    ``lower_options`` sets a smaller limit of its own."""
    _check_perfectly_plastic(disc)
    check_hencky(disc, "the limit load")
    check_not_axisymmetric(disc.problem, "the limit load")
    options, lower_options = LimitOptions.of(options), LowerBoundOptions.of(lower_options, "lower_options")
    check_lower_bound_size(disc, lower_options, limit=True)  # before the kinematic program, which would run first
    t0 = time.perf_counter()
    upper = kinematic_limit_load(disc, options)
    if options.time_limit is not None:
        left = max(options.time_limit - (time.perf_counter() - t0), MIN_LOWER_TIME)
        if lower_options.time_limit is None or lower_options.time_limit > left:
            lower_options = replace(lower_options, time_limit=left)
    lower = static_limit_load(disc, lower_options)
    notes = [f"upper: {upper.message}", f"lower: {lower.message}"]
    return LimitBracket(F_lower=float(lower.F_lower), F_upper=upper.F_upper,
                        certified=bool(upper.certified and lower.certified), upper=upper, lower=lower,
                        message="; ".join(notes))


__all__ = ["KinematicBound", "LimitBracket", "LimitOptions", "VelocitySpace", "dissipation", "kinematic_limit_load",
           "limit_load", "obstacle_note", "velocity_space"]
