"""The iterative linear-algebra path (issue 12) against the direct one, on small meshes.

Every comparison is with another formulation of the same quantity: the block
assembly against ``Discretization.weighted_gram`` (sparse triple product), AMG-CG
against a sparse direct solve, the iterative contact projection against its own
optimality conditions, and every method's answer forced onto the iterative path
against the same method on the direct path. The agreement asked by the issue:
U to 1e-8 (relative), stresses to 1e-6 in the energy norm, and both answers
passing the same certificate at the same tolerance.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import elastoplast as ep
from conftest import build, cylinder_dict, energy_error, sphere_quarter_dict
from elastoplast.fem.assembly import assemble, element_geometry
from elastoplast.linalg.amg import FaceSystems, contact_dofs
from elastoplast.linalg.blocks import block_layout, bsr
from elastoplast.solvers.newton import NEWTON_AMG_FROM_ELEMENTS, choose_backend, energy, forcing_term
from elastoplast.solvers.registry import CONIC_MAX_ELEMENTS
from elastoplast.certificate.kkt import abs_transpose_product, gaps
from elastoplast.fem.discretize import free_strain_operator, nondimensionalize
from elastoplast.errors import InputError
from elastoplast.fem.material import consistent_tangent
from elastoplast.mesh.topology import boundary_facets
from elastoplast.mesh.base import structured_mesh
from elastoplast.solvers.contact import IterativeProjection

TOL = 1e-9


@pytest.fixture(scope="module")
def quarter():
    """3D, two symmetry planes (single fixed components), a plastic zone."""
    return build(sphere_quarter_dict((6, 6, 5), hardening=2000.0))


@pytest.fixture(scope="module")
def cylinder():
    """2D plane strain, a plastic zone."""
    return build(cylinder_dict((40, 20)))


def agree(disc, a: ep.Solution, b: ep.Solution) -> None:
    assert a.converged and b.converged, (a.message, b.message)
    assert abs(a.U - b.U) <= 1e-8 * abs(b.U)
    assert energy_error(disc, a, b) <= 1e-6


# ----------------------------------------------------------------------------
# operators
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("dim", [2, 3])
def test_strain_operator_is_exact_on_linear_fields(dim):
    """P1 elements reproduce linear displacements: ``u = A x`` has the strain
    sym(A) in every element (Mandel: off-diagonals times sqrt 2)."""
    size, div = ([2.0, 1.0], [7, 4]) if dim == 2 else ([2.0, 2.0, 1.0], [4, 3, 3])
    mesh = structured_mesh(size, div, 0.5, grading=1.4)
    _, grads = element_geometry(mesh)
    B = free_strain_operator(mesh, grads, np.arange(mesh.n_nodes * dim), chunk=17)
    A = np.random.default_rng(dim).standard_normal((dim, dim))
    eps = B @ (mesh.points @ A.T).ravel()
    S = 0.5 * (A + A.T)
    r2 = np.sqrt(2.0)
    expected = [S[0, 0], S[1, 1], 0.0, r2 * S[0, 1]] if dim == 2 else \
        [S[0, 0], S[1, 1], S[2, 2], r2 * S[1, 2], r2 * S[0, 2], r2 * S[0, 1]]
    np.testing.assert_allclose(eps.reshape(mesh.n_elements, -1), np.tile(expected, (mesh.n_elements, 1)),
                               atol=1e-12 * np.abs(A).max())


def test_boundary_facets_of_a_box():
    """A box of nx x ny x nz cubes, each face split into two triangles, has
    4 (nx ny + ny nz + nx nz) boundary facets, each on one of the six planes."""
    nx, ny, nz = 5, 4, 3
    mesh = structured_mesh([5.0, 4.0, 3.0], [nx, ny, nz], 1.0, origin=[0.0, 0.0, 0.0])
    facets = boundary_facets(mesh.cells)
    assert facets.shape == (4 * (nx * ny + ny * nz + nx * nz), 3)
    X = mesh.points[facets]
    on_plane = np.zeros(len(facets), dtype=bool)
    for axis, hi in enumerate([5.0, 4.0, 3.0]):
        for val in (0.0, hi):
            on_plane |= np.all(np.abs(X[:, :, axis] - val) < 1e-12, axis=1)
    assert on_plane.all()
    assert len({tuple(f) for f in facets}) == len(facets)


@pytest.mark.parametrize("name", ["quarter", "cylinder"])
def test_block_assembly_matches_the_gram_product(name, request):
    """``sum_T |T| B_T^T D_T B_T`` assembled block by block equals the sparse
    triple product ``B^T diag(|T| D_T) B`` of ``weighted_gram``, for one D and
    for per-element tangents (with the plastic correction added to C's)."""
    disc = request.getfixturevalue(name)
    nd, units = nondimensionalize(disc)
    lay = block_layout(nd, units.length)
    C = nd.material.stiffness(nd.dim)
    data = assemble(lay, C)
    full = bsr(lay, data).tocsr()[nd.free][:, nd.free]
    K = nd.weighted_gram(C)
    assert abs(full - K).max() <= 1e-12 * abs(K).max()
    rng = np.random.default_rng(0)
    eps = 3.0 * rng.standard_normal((nd.n_elements, nd.k)) * nd.material.yield_stress
    _, _, tangent = consistent_tangent(nd.material, eps)
    plastic = np.flatnonzero(np.any(tangent != C, axis=(1, 2)))
    assert 0 < plastic.size < nd.n_elements
    corrected = assemble(lay, tangent[plastic], plastic, out=data.copy(), subtract=C)
    Kt = nd.weighted_gram(tangent)
    got = bsr(lay, corrected).tocsr()[nd.free][:, nd.free]
    assert abs(got - Kt).max() <= 1e-12 * abs(Kt).max()


def test_abs_transpose_product_in_chunks(quarter, monkeypatch):
    import elastoplast.certificate.kkt as certificate

    x = np.random.default_rng(1).standard_normal(quarter.B.shape[0])
    monkeypatch.setattr(certificate, "ABS_CHUNK_ROWS", 97)
    np.testing.assert_allclose(abs_transpose_product(quarter.B, x), abs(quarter.B).T @ x, rtol=1e-13, atol=0)


# ----------------------------------------------------------------------------
# AMG-preconditioned CG
# ----------------------------------------------------------------------------


def test_bordered_system_against_a_direct_solve(quarter):
    """CG on ``[[A, b], [b^T, c]]`` (Newton's face system: active contact dofs
    fixed, U coupled to every contact dof) to relative residual 1e-10 gives the
    sparse direct solution of the same matrix, also with a hierarchy built for
    another face (kept across steps)."""
    nd, units = nondimensionalize(quarter)
    lay = block_layout(nd, units.length)
    cdofs = contact_dofs(nd)
    faces = FaceSystems(lay, nd.free, cdofs, assemble(lay, nd.material.stiffness(3)), reuse=True)
    n = nd.n_free + 1
    H = sp.csr_matrix(np.column_stack([faces.matvec(e) for e in np.eye(n)]))
    assert abs(H - H.T).max() <= 1e-12 * abs(H).max()
    rhs = np.random.default_rng(2).standard_normal(n)
    for active in (cdofs[:3], cdofs[1:6]):  # the second solve keeps the first hierarchy
        fixed = np.zeros(n, dtype=bool)
        fixed[active] = True
        x, info = faces.solve(fixed, rhs, 1e-10)
        F = np.flatnonzero(~fixed)
        exact = spla.spsolve(H[F][:, F].tocsc(), rhs[F])
        assert np.all(x[fixed] == 0.0)
        assert np.linalg.norm(x[F] - exact) <= 1e-7 * np.linalg.norm(exact)
        assert info["cg_residual"] <= 1e-10
    assert faces.setups >= 1


def test_forcing_term():
    """Eisenstat-Walker choice 2 with the safeguard, the cap and the no-oversolving floor."""
    assert forcing_term(0.5, None, None, 1e-2, 1e-8) == 1e-2
    assert forcing_term(1e-3, 1e-1, 1e-2, 1.0, 1e-12) == pytest.approx(0.9 * 1e-4)
    assert forcing_term(0.5, 0.6, 0.9, 1.0, 1e-8) == pytest.approx(0.9 * 0.9**2)  # safeguard
    assert forcing_term(1e-6, 1e-2, 1e-2, 1e-2, 1e-8) == pytest.approx(0.1 * 1e-8 / 1e-6)  # floor
    assert forcing_term(1e-1, 1e-1, 1e-2, 1e-2, 1e-8) == 1e-2  # cap


# ----------------------------------------------------------------------------
# the methods on the iterative path against the direct path
# ----------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["quarter", "cylinder"])
def test_newton_amg_matches_direct(name, request):
    disc = request.getfixturevalue(name)
    direct = ep.solve(disc, "newton", tol=TOL, linear_solver="splu")
    amg = ep.solve(disc, "newton", tol=TOL, linear_solver="amg")
    assert "amg" in amg.message
    agree(disc, amg, direct)
    np.testing.assert_array_equal(amg.active, direct.active)
    np.testing.assert_array_equal(amg.plastic, direct.plastic)
    # the linear solves were inexact early on and tightened toward the end
    cg = [h for h in amg.history if "cg_iterations" in h]
    assert cg[0]["forcing"] >= 1e-3 and min(h["forcing"] for h in cg) < 1e-3


@pytest.mark.parametrize("method", ["uzawa", "uzawa-fast"])
def test_uzawa_amg_matches_direct(method, quarter):
    direct = ep.solve(quarter, method, tol=TOL)
    amg = ep.solve(quarter, method, tol=TOL, factorization="amg")
    assert "AMG-CG" in amg.message
    agree(quarter, amg, direct)


def test_alg2_amg_matches_direct(cylinder):
    direct = ep.solve(cylinder, "uzawa-fast", tol=1e-8, variant="alg2")
    amg = ep.solve(cylinder, "uzawa-fast", tol=1e-8, variant="alg2", factorization="amg")
    assert "AMG-CG" in amg.message
    assert abs(amg.U - direct.U) <= 1e-7 * abs(direct.U)
    assert energy_error(cylinder, amg, direct) <= 1e-6


@pytest.mark.parametrize("name", ["quarter", "cylinder"])
def test_iterative_projection_meets_its_optimality_conditions(name, request):
    """Step (ii) by the primal-dual active set on AMG-CG: stationarity
    ``G (v - u) + rho r = N^T lam``, ``w (V - U) - rho F = -sum lam`` to the CG
    tolerance, ``lam >= 0``, gaps >= 0 and complementarity."""
    disc = request.getfixturevalue(name)
    nd, units = nondimensionalize(disc)
    proj = IterativeProjection(nd, units.length, np.eye(nd.k), rtol=1e-12)
    rng = np.random.default_rng(3)
    u = 1e-2 * rng.standard_normal(nd.n_free)
    r = rng.standard_normal(nd.n_free)
    rho, U = 0.5, 0.3
    v, V, lam = proj(u, U, r, rho, nd.force, nd.N, nd.psi)
    G = nd.weighted_gram(np.eye(nd.k))
    res = G @ (v - u) + rho * r - nd.N.T @ lam
    assert np.linalg.norm(res) <= 1e-9 * np.linalg.norm(rho * r)
    assert proj.weight * (V - U) == pytest.approx(rho * nd.force - lam.sum(), rel=1e-8)
    g = gaps(nd, v, V)
    assert lam.min() >= 0 and lam.max() > 0 and g.min() >= 0.0
    assert np.abs(lam * g).max() <= 1e-9 * lam.max() * np.abs(g).max()


# ----------------------------------------------------------------------------
# choices by size
# ----------------------------------------------------------------------------


def test_auto_takes_amg_from_the_crossover(quarter, monkeypatch):
    monkeypatch.setitem(NEWTON_AMG_FROM_ELEMENTS["pardiso"], 3, quarter.n_elements)
    monkeypatch.setitem(NEWTON_AMG_FROM_ELEMENTS["splu"], 3, quarter.n_elements)
    assert choose_backend(quarter, "auto") == "amg"
    assert choose_backend(quarter, "splu") == "splu"
    monkeypatch.setitem(NEWTON_AMG_FROM_ELEMENTS["pardiso"], 3, quarter.n_elements + 1)
    monkeypatch.setitem(NEWTON_AMG_FROM_ELEMENTS["splu"], 3, quarter.n_elements + 1)
    assert choose_backend(quarter, "auto") in ("pardiso", "splu")


def test_conic_refuses_beyond_its_size(quarter, monkeypatch):
    monkeypatch.setitem(CONIC_MAX_ELEMENTS, 3, quarter.n_elements - 1)
    with pytest.raises(InputError) as err:
        ep.solve(quarter, "conic")
    assert err.value.field == "method"
    assert f"{quarter.n_elements:,}" in err.value.message
    for method in ("newton", "uzawa", "uzawa-fast"):
        assert method in err.value.message


def test_newton_energy_is_the_displacement_form(quarter):
    """The line search's energy from one return mapping equals value(D) of solution.py."""
    from elastoplast.fem.material import return_mapping
    from elastoplast.certificate.solution import value_displacement_form

    nd, _ = nondimensionalize(quarter)
    u = 3.0 * np.random.default_rng(4).standard_normal(nd.n_free)
    sigma, xi, kappa = return_mapping(nd.material, nd.strain(u))
    assert kappa.max() > 0 and kappa.min() == 0
    assert energy(nd, sigma, kappa, 0.7) == pytest.approx(value_displacement_form(nd, u, 0.7), rel=1e-12)
