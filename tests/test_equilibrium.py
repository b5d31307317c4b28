"""The certified lower bound -J <= Pi* of the equilibrium element (docs/bounds.md).

Where the numbers come from:
* patch tests: the uniaxial-strain closed form of tests/test_patch.py (a uniform
  stress lies in the equilibrium element, so its optimum is the continuum optimum);
* lower <= value_D: weak duality of docs/bounds.md with the P1 interpolant of psi. For
  (v, V) in K_h (non-penetration at the nodes) and P1 v, ``v_d - V + I_h psi`` is
  linear on each contact facet and >= 0 at its vertices, so ``int lam (v_d - V +
  I_h psi) >= 0`` for lam >= 0, and Pi(u_h, U_h) = value_D >= -J holds even for
  curved psi, where u_h may penetrate between nodes;
* limit load: the lower-bound theorem F_lower <= F_c and Prandtl's (2 + pi) k B;
* CVXPY: the same model written again from facet normals (not the program's
  gradient rows) and solved by CVXPY.
"""

from __future__ import annotations

import copy
import warnings
from dataclasses import replace

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import PROBLEMS, build, cylinder_dict, sphere_quarter_dict
from test_limit_load import PRANDTL_FORCE, punch
from test_patch import E, H, NU, SY, patch_problem, uniaxial_strain

import elastoplast as ep
from elastoplast.fem.material import n_components
from elastoplast.fem.stress_form import deviatoric_basis
from elastoplast.bounds.static import CERTIFY_TOL, certify_static, mass_matrix, psi_weights, traction_operator
from elastoplast.bounds.lower import LowerBoundOptions
from elastoplast.bounds.equilibrium.bound import program_field, solve_program, repaired_field, lower_bound_setup, solve_lower_bound, static_limit_load
from elastoplast.bounds.equilibrium.program import lower_bound_program
from elastoplast.bounds.equilibrium.repair import repair_static
from elastoplast.mesh.topology import facet_measure, facet_topology, outward_facet_normals
from elastoplast.fem.assembly import element_geometry
from elastoplast.mesh.topology import boundary_facets
from elastoplast.bounds.local.construction import split_discretization


def patch_force(dim: int, stress_ratio: float, m: ep.Material) -> float:
    """The force on the uniaxial-strain patch (bottom area 3 in 2D, 6 in 3D) at ``stress_ratio``
    times the axial stress of first yield, (lam + 2 mu) sigma_y / (2 mu)."""
    first_yield = (m.lam + 2 * m.mu) * m.yield_stress / (2 * m.mu)
    return stress_ratio * first_yield * (3.0 if dim == 2 else 6.0)


def closed_form_energy(dim: int, F: float, m: ep.Material) -> tuple[float, float]:
    """``(J*, Pi*)`` of the uniaxial-strain patch: J* = 1/2 |Omega| (sigma A sigma + xi^2/H)
    and Pi* = |Omega| W(eps) - F U with W from the return mapping (docs/bounds.md)."""
    A_bottom, height = (3.0, 2.0) if dim == 2 else (6.0, 2.0)
    e, _ = uniaxial_strain(F / A_bottom, m)
    eps = np.zeros((1, n_components(dim)))
    eps[0, dim - 1] = -e
    sig, xi, _ = ep.return_mapping(m, eps)
    C, A = m.stiffness(dim), m.compliance(dim)
    vol = A_bottom * height
    J = 0.5 * vol * (sig[0] @ A @ sig[0] + xi[0] ** 2 / m.hardening)
    trial = eps[0] @ C
    W = 0.5 * trial @ eps[0] - 0.5 * ((trial - sig[0]) @ A @ (trial - sig[0]) + xi[0] ** 2 / m.hardening)
    return J, vol * W - F * e * height


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("stress_ratio", [0.5, 3.0], ids=["elastic", "plastic"])
def test_patch_lower_bound_is_the_closed_form(dim, stress_ratio):
    m = ep.Material(E, NU, SY, H)
    F = patch_force(dim, stress_ratio, m)
    disc = ep.discretize(patch_problem(dim, F))
    lb = solve_lower_bound(disc)
    J_exact, Pi_exact = closed_form_energy(dim, F, m)
    assert J_exact == pytest.approx(-Pi_exact, rel=1e-12)  # the closed form itself: no duality gap
    assert lb.certified, lb.message
    assert -lb.J == pytest.approx(Pi_exact, rel=1e-8)
    assert lb.certificate.worst <= CERTIFY_TOL
    # the P1 displacement solution attains the same value from above
    sol = ep.solve(disc, "conic")
    assert sol.value_D == pytest.approx(Pi_exact, rel=1e-8)
    # local terms add up to J; the contact pressures to F
    assert lb.element_energy.sum() + lb.local.facet_psi_work.sum() == pytest.approx(lb.J, rel=1e-14)
    assert lb.local.facet_force.sum() == pytest.approx(F, rel=1e-13)
    # the field is the uniform stress, axial -F/A at every vertex, to the accuracy that
    # an energy gap g allows: ||sigma - tau|| <= sqrt(2 g) (docs/bounds.md), g ~ 1e-12 J here
    assert np.allclose(lb.field.tau[..., dim - 1], -F / (3.0 if dim == 2 else 6.0), rtol=1e-5)


@pytest.fixture(scope="module")
def cylinder_small():
    disc = build(cylinder_dict(divisions=(24, 12)))
    return disc, solve_lower_bound(disc)


def test_facet_topology_counts(cylinder_small):
    disc, _ = cylinder_small
    mesh = disc.mesh
    topo = facet_topology(mesh, disc.problem.boundary)
    d = mesh.dim
    # every element facet is counted once as boundary or twice as interior
    assert 2 * topo.interior_elements.shape[0] + topo.boundary_elements.size == mesh.n_elements * (d + 1)
    np.testing.assert_array_equal(np.sort(topo.boundary_nodes, axis=1)[np.lexsort(topo.boundary_nodes.T[::-1])],
                                  boundary_facets(mesh.cells))
    # the contact facets are the contact group's, the clamped sides are fully fixed
    assert topo.contact.sum() == mesh.groups["contact"].shape[0]
    clamped = np.isin(np.arange(topo.boundary_elements.size),
                      np.flatnonzero(topo.fixed.all(axis=1)))
    assert clamped.sum() == sum(mesh.groups[g].shape[0] for g in disc.problem.boundary.clamped)
    # the bottom outside the contact zone is free: both traction components vanish there
    free = ~topo.fixed.any(axis=1) & ~topo.contact
    assert free.sum() == mesh.groups["bottom"].shape[0] - mesh.groups["contact"].shape[0]
    assert topo.zero_traction[free].all()


def brute_force_facets(cells):
    """Each facet (sorted node tuple) with the (element, opposite local vertex) pairs that hold it,
    by a Python dictionary: the reference of the vectorised facet topology."""
    held = {}
    for e, cell in enumerate(cells.tolist()):
        for j in range(len(cell)):
            held.setdefault(tuple(sorted(cell[:j] + cell[j + 1:])), []).append((e, j))
    return held


@pytest.mark.parametrize("make", [lambda: build(cylinder_dict(divisions=(6, 4))),
                                  lambda: build(sphere_quarter_dict(divisions=(3, 3, 2))),
                                  lambda: split_discretization(build(sphere_quarter_dict(divisions=(3, 3, 2)))).disc],
                         ids=["2d", "3d", "3d split"])
def test_facet_topology_is_the_brute_force_pairing(make):
    disc = make()
    cells = disc.mesh.cells
    topo = facet_topology(disc.mesh, disc.problem.boundary)
    held = brute_force_facets(cells)
    interior = {f: sorted(v) for f, v in held.items() if len(v) == 2}
    got = {tuple(n): sorted(zip(e.tolist(), j.tolist()))
           for n, e, j in zip(topo.interior_nodes.tolist(), topo.interior_elements, topo.interior_local)}
    assert got == interior
    boundary = {f: v for f, v in held.items() if len(v) == 1}
    got_b = {tuple(n): [(int(e), int(j))] for n, e, j in zip(topo.boundary_nodes.tolist(), topo.boundary_elements,
                                                           topo.boundary_local)}
    assert got_b == boundary
    # the local vertex indices name the facet's nodes in each element, and the opposite vertex is not on it
    for s in range(2):
        np.testing.assert_array_equal(cells[topo.interior_elements[:, s, None], topo.interior_vertices[:, s]],
                                      topo.interior_nodes)
    np.testing.assert_array_equal(cells[topo.boundary_elements[:, None], topo.boundary_vertices], topo.boundary_nodes)


def test_certificate_refuses_perturbed_fields(cylinder_small):
    disc, lb = cylinder_small
    assert lb.certified, lb.message
    f = lb.field
    cert = lambda g: certify_static(disc, g)  # noqa: E731
    tau = f.tau.copy()
    e, a = np.unravel_index(np.argmax(np.linalg.norm(tau, axis=2)), tau.shape[:2])
    tau[e, a, 0] += 1e-9 * lb.certificate.scale  # one component of one vertex value
    bad = cert(replace(f, tau=tau))
    assert set(bad.failed) & {"equilibrium", "traction_jump"}
    lam = f.lam.copy()
    lam[np.unravel_index(np.argmax(lam), lam.shape)] *= 1 + 1e-9
    bad = cert(replace(f, lam=lam))
    assert set(bad.failed) == {"contact_normal", "force_balance"}
    eta = f.eta.copy()
    vm = ep.von_mises(f.tau.reshape(-1, disc.k)).reshape(eta.shape)
    worst = np.argmax(vm - eta)
    eta.flat[worst] = vm.flat[worst] - disc.material.yield_stress - 1e-6 * disc.material.yield_stress
    bad = cert(replace(f, eta=eta))
    assert bad.failed == ("yield_excess",)
    bad = certify_static(disc.with_force(disc.force * (1 + 1e-9)), f)  # a field for another load
    assert bad.failed == ("force_balance",)


def test_certificate_by_blocks_is_the_certificate_at_once(cylinder_small, monkeypatch):
    """The certificate's batched operators and the von Mises stress are computed in blocks;
    with blocks of 7 elements (or rows) every residual is the one computed at once (the same
    rows, maxima of maxima), and a NaN in the last block is not lost between blocks."""
    from elastoplast.bounds import static
    from elastoplast.fem import material

    disc, lb = cylinder_small
    whole = certify_static(disc, lb.field).as_dict()
    monkeypatch.setattr(static, "CERTIFY_BLOCK", 7)
    monkeypatch.setattr(material, "VON_MISES_ROWS", 7)
    assert certify_static(disc, lb.field).as_dict() == whole
    vm = ep.von_mises(lb.field.tau)
    monkeypatch.setattr(material, "VON_MISES_ROWS", 1 << 20)
    np.testing.assert_array_equal(vm, ep.von_mises(lb.field.tau))
    monkeypatch.setattr(material, "VON_MISES_ROWS", 7)
    tau = lb.field.tau.copy()
    tau[-1, -1, 0] = np.nan  # the last vertex value of the last element: the last block
    bad = certify_static(disc, replace(lb.field, tau=tau))
    assert not bad.passed and np.isnan(bad.traction_jump) and np.isnan(bad.yield_excess)


def test_certificate_refuses_a_dropped_traction_row_and_raw_solver_output():
    """A program missing one traction-continuity row finds a field with a traction
    jump there, which the certificate names; the raw interior point (before the
    repair) fails too: its residuals are at the solver's tolerance."""
    disc = build(cylinder_dict(divisions=(16, 8)))
    opt = LowerBoundOptions()
    s = lower_bound_setup(disc, opt)
    q_nd = s.psi.q / (s.units.displacement * s.units.length ** (disc.dim - 1))
    prog = lower_bound_program(s.nd, s.topo, s.grads, q_nd)
    x = solve_program(disc, prog, opt, "clarabel").x
    raw = certify_static(disc, program_field(s, prog, x, disc.force))
    assert not raw.passed

    # drop the tangential-traction row of the most loaded interior facet vertex
    n, d = disc.n_elements, disc.dim
    field = repaired_field(disc, s, prog, x)[0]
    ie, iv = s.topo.interior_elements[:, 0], s.topo.interior_vertices[:, 0]
    load = np.linalg.norm(field.tau[ie[:, None], iv], axis=2).max(axis=1)
    f = int(np.argmax(load))
    row = n * d + (f * d + 0) * d + 0  # facet f, its first vertex, x component
    keep = np.ones(prog.A.shape[0], dtype=bool)
    keep[row] = False
    cones = [type(prog.cones[0])(prog.n_eq - 1)] + prog.cones[1:]
    dropped = replace(prog, A=prog.A[keep].tocsc(), b=prog.b[keep], cones=cones, n_eq=prog.n_eq - 1)
    ans = solve_program(disc, dropped, opt, "clarabel")
    x2 = ans.x
    field2, resid, _ = repaired_field(disc, s, dropped, x2)
    assert resid < 1e-14
    bad = certify_static(disc, field2)
    assert bad.failed == ("traction_jump",)


def cvxpy_lower_bound(disc: ep.Discretization) -> float:
    """The equilibrium-element program written again in CVXPY, from unit outward facet
    normals and measures (outward_facet_normals); the unknowns are in units of the mean
    contact pressure S and lengths in units of the mesh's extent. Returns its optimum J."""
    import cvxpy as cp

    mesh, m, d, k = disc.mesh, disc.material, disc.dim, disc.k
    n = disc.n_elements
    topo = facet_topology(mesh, disc.problem.boundary)
    S = disc.force / disc.contact_area.sum()  # stress unit
    tau = cp.Variable(((d + 1) * n, k))  # row e (d+1) + a
    eta = cp.Variable((d + 1) * n)
    lam = cp.Variable(topo.contact_facets.size)  # row f d + j
    sel = lambda rows: sp.csr_matrix((np.ones(rows.size), (np.arange(rows.size), rows)), shape=(rows.size, (d + 1) * n))  # noqa: E731

    def traction(elements, local_vertices, nodes, j):
        """tau n at facet vertex j of each facet, as a (facets, d) expression."""
        nrm = outward_facet_normals(mesh.points, mesh.cells, elements, nodes)
        t = sel(elements * (d + 1) + local_vertices[:, j]) @ tau  # (m, k)
        N = traction_operator(nrm)  # (m, d, k)
        return cp.hstack([cp.reshape(cp.sum(cp.multiply(N[:, r, :], t), axis=1), (-1, 1), order="F") for r in range(d)])

    cons = []
    _, grads = element_geometry(mesh)
    for r in range(d):  # div tau = 0
        cons.append(sum(cp.sum(cp.multiply(traction_operator(grads[:, a])[:, r, :], sel(np.arange(n) * (d + 1) + a) @ tau),
                               axis=1) for a in range(d + 1)) == 0)
    for j in range(d):
        cons.append(traction(topo.interior_elements[:, 0], topo.interior_vertices[:, 0], topo.interior_nodes, j)
                    + traction(topo.interior_elements[:, 1], topo.interior_vertices[:, 1], topo.interior_nodes, j) == 0)
        t = traction(topo.boundary_elements, topo.boundary_vertices, topo.boundary_nodes, j)
        zero = topo.zero_traction
        pick = lambda rows: sp.csr_matrix((np.ones(rows.size), (np.arange(rows.size), rows)),  # noqa: E731
                                          shape=(rows.size, t.shape[0]))
        for r in range(d):
            if zero[:, r].any():
                cons.append(pick(np.flatnonzero(zero[:, r])) @ t[:, r] == 0)
        ci = topo.contact_index
        cons.append(pick(ci) @ t[:, d - 1] == lam[np.arange(ci.size) * d + j])
    measure = facet_measure(mesh.points[topo.contact_facets])
    ell = disc.length_scale
    cons += [lam >= 0, cp.sum(cp.multiply(np.repeat(measure / (d * ell ** (d - 1)), d), lam)) == disc.force / (S * ell ** (d - 1))]
    Q = deviatoric_basis(k)
    cons.append(cp.SOC(m.yield_stress / S + eta, np.sqrt(1.5) * (tau @ Q).T, axis=0))
    M = mass_matrix(d)
    L = np.linalg.cholesky(np.kron(np.diag(disc.volumes / ell**d), M))  # vertex mass matrix
    unit = S**2 / m.E * ell**d  # energy of the unknowns' units
    energy = 0.5 * cp.sum_squares(L.T @ (tau @ np.linalg.cholesky(m.compliance(d) * m.E)))
    energy += 0.5 * cp.sum_squares(L.T @ eta) * m.E / m.hardening
    psi = psi_weights(disc, topo).q.ravel()
    prob = cp.Problem(cp.Minimize(energy + psi @ lam * S / unit), cons)
    prob.solve(solver=cp.CLARABEL, tol_gap_abs=1e-10, tol_gap_rel=1e-10, tol_feas=1e-10)
    assert prob.status == cp.OPTIMAL
    return prob.value * unit


@pytest.mark.parametrize("case", ["cylinder", "quarter"])
def test_cvxpy_model_agrees(case):
    data = cylinder_dict(divisions=(8, 4)) if case == "cylinder" else sphere_quarter_dict(divisions=(3, 3, 2))
    disc = build(data)
    lb = solve_lower_bound(disc)
    assert lb.certified, lb.message
    assert cvxpy_lower_bound(disc) == pytest.approx(lb.J_solver, rel=1e-6)
    assert lb.J == pytest.approx(lb.J_solver, rel=1e-6)  # the repair costs nothing visible


@pytest.mark.parametrize("case", ["cylinder-graded", "quarter-sphere", "punch-gmsh"])
def test_lower_bound_below_the_p1_energy(case):
    if case == "cylinder-graded":
        disc = build(cylinder_dict(divisions=(24, 12)))
    elif case == "quarter-sphere":
        disc = build(sphere_quarter_dict(divisions=(3, 3, 3)))
    else:
        disc = ep.discretize(ep.load_problem(PROBLEMS / "punch_2d_gmsh.toml"))
    lb = solve_lower_bound(disc)
    assert lb.certified, lb.message
    sol = ep.solve(disc, "conic")
    assert sol.converged
    assert -lb.J <= sol.value_D


def flat_punch(divisions) -> ep.Discretization:
    return ep.discretize(ep.problem_from_dict({
        "mesh": {"generator": "rectangle", "size": [8.0, 4.0], "divisions": list(divisions), "grading": 1.3,
                 "contact_radius": 1.0},
        "material": {"E": 200e3, "nu": 0.3, "yield_stress": 250.0, "hardening": 20e3},
        "obstacle": {"shape": "flat"},
        "load": {"force": 600.0},
    }))


def test_no_lower_bound_exceeds_any_upper_bound_under_refinement():
    """Flat psi: the P1 solution is in K exactly (linear gaps >= 0 at the nodes), so
    value_D = Pi(u_h, U_h) >= Pi* on every mesh; every -J is <= Pi*."""
    lowers, uppers = [], []
    for div in ([8, 4], [16, 8], [32, 16]):
        disc = flat_punch(div)
        lb = solve_lower_bound(disc)
        assert lb.certified, lb.message
        sol = ep.solve(disc, "conic")
        assert sol.converged and sol.kkt.worst < 1e-8
        lowers.append(-lb.J)
        uppers.append(sol.value_D)
    assert max(lowers) <= min(uppers)
    # the bracket shrinks
    gaps = np.array(uppers) - np.array(lowers)
    assert np.all(np.diff(gaps) < 0)


def test_static_limit_load_below_prandtl():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        disc = punch("crossed")
    lim = static_limit_load(disc)
    assert lim.certified, lim.message
    assert lim.F_lower <= PRANDTL_FORCE  # lower-bound theorem: F_lower <= F_c (Prandtl's field fits the block)
    assert lim.F_lower >= 0.6 * PRANDTL_FORCE  # a meaningful bound on a mesh of spacing w/6 under the punch
    assert lim.certificate.yield_excess == 0.0
    # below it the H = 0 energy program has a certified field; above it none exists
    lb = solve_lower_bound(disc.with_force(0.95 * lim.F_lower))
    assert lb.certified, lb.message
    with pytest.raises(ep.InputError, match="load.force"):
        solve_lower_bound(disc.with_force(1.05 * lim.F_lower))


def test_expression_obstacle_is_enclosed():
    """A paraboloid written as an expression: the interval enclosure gives a certified
    bound close to the convex-interpolant one, both below the P1 energy."""
    data = cylinder_dict(divisions=(24, 12))
    data["obstacle"] = {"shape": "paraboloid", "radius": 40.0}
    parab = build(data)
    data = copy.deepcopy(data)
    data["obstacle"] = {"shape": "expression", "expression": "x**2 / 80.0"}
    expr = build(data)
    lb_p, lb_e = solve_lower_bound(parab), solve_lower_bound(expr)
    assert lb_p.certified and lb_e.certified, lb_e.message
    assert "interval" in lb_e.psi_method
    sol = ep.solve(parab, "conic")
    assert -lb_e.J <= sol.value_D and -lb_p.J <= sol.value_D
    assert -lb_e.J == pytest.approx(-lb_p.J, rel=0.05)
    # weights are over-estimates of int psi b_a: compare with a fine quadrature
    topo = facet_topology(expr.mesh, expr.problem.boundary)
    q = psi_weights(expr, topo).q
    X = expr.mesh.points[topo.contact_facets][:, :, 0]
    t = (np.arange(2000) + 0.5) / 2000
    x = X[:, :1] * (1 - t) + X[:, 1:] * t
    exact = np.stack([((1 - t) * x**2 / 80).mean(axis=1), (t * x**2 / 80).mean(axis=1)], axis=1) * np.abs(X[:, 1:] - X[:, :1])
    assert np.all(q >= exact - 1e-9 * np.abs(exact).max())


def test_expression_that_cannot_be_enclosed_is_not_certified():
    data = cylinder_dict(divisions=(8, 4))
    data["obstacle"] = {"shape": "expression", "expression": "where(x > -100, x**2 / 80.0, 1 / x)"}
    disc = build(data)
    lb = solve_lower_bound(disc)
    assert not lb.certified
    assert "division by an interval" in lb.message


def test_bad_input():
    disc = build(cylinder_dict(divisions=(8, 4)))
    mesh = disc.mesh
    # a contact group whose facets are no faces of the mesh
    groups = dict(mesh.groups)
    groups["ghost"] = np.array([[0, mesh.n_nodes - 1]])
    with pytest.raises(ep.InputError, match="boundary.contact"):
        facet_topology(ep.Mesh(mesh.points, mesh.cells, groups),
                          ep.Boundary(clamped=(), contact=("ghost",)))
    # a field on other contact facets
    lb = solve_lower_bound(disc)
    with pytest.raises(ep.InputError, match="contact_facets"):
        certify_static(disc, replace(lb.field, contact_facets=lb.field.contact_facets[::-1]))


def test_repair_handles_redundant_rows():
    """On the crossed pattern the traction rows at a centre node (two straight lines
    of edges through it) are linearly dependent: 4 elements x 3 stress components
    leave 5 free parameters against 8 rows, rank 7. The projection still reaches
    round-off and the solver's field is certified."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        disc = ep.discretize(ep.problem_from_dict({
            "mesh": {"generator": "rectangle", "size": [4.0, 2.0], "divisions": [4, 2], "contact_radius": 1.0,
                     "pattern": "crossed"},
            "material": {"E": 200e3, "nu": 0.3, "yield_stress": 250.0, "hardening": 0.0},
            "obstacle": {"shape": "flat"},
            "load": {"force": 100.0},
        }))
    opt = LowerBoundOptions()
    s = lower_bound_setup(disc, opt)
    prog = lower_bound_program(s.nd, s.topo, s.grads, s.psi.q)
    A = prog.A[: prog.n_eq].toarray()
    assert np.linalg.matrix_rank(A) < A.shape[0]
    x = solve_program(disc, prog, opt, "clarabel").x
    _, resid, _ = repair_static(prog, x)
    assert resid < 1e-14
    lb = solve_lower_bound(disc)
    assert lb.certified, lb.message
