"""A lower bound built locally from the P1 solution (docs/bounds.md, "the local lower bound").

With H > 0 every statically admissible stress field bounds the energy from below once
its hardening stress is large enough (``eta = max(0, vm(tau) - sigma_y)``). The field
built here is exactly admissible and costs a few batched passes over the mesh:

1. the discrete stress, corrected near Γ0 so that its nodal balance holds with a
   non-negative linear contact pressure (:mod:`elastoplast.bounds.local.contact`);
2. equilibrated facet tractions, vertex star by vertex star (:mod:`elastoplast.bounds.local.equilibrate`);
3. their exact lift into each element on its barycentric split (:mod:`elastoplast.bounds.local.lift`);
4. optionally, sweeps of ring-local complementary-energy minimisation (edge patches in
   3D, vertex stars in 2D: :mod:`elastoplast.bounds.local.rings`, :mod:`elastoplast.bounds.local.sweeps`),
   each keeping the field admissible and moving the contact pressure too (``lam >= 0``
   and ``int lam = F`` kept), then the round-off repair of the elements' balance, ring by
   ring (:func:`~elastoplast.bounds.local.sweeps.ring_repair`; nothing global is factored);
5. in plane strain ``tau33 = nu (tau11 + tau22) + offset`` (:func:`out_of_plane_offset`),
   then moved towards each sub-element's minimiser of J (:func:`optimal_tau33`; no
   equilibrium row involves it), ``eta`` at every sub-element vertex as above; the field lives on the split mesh,
   where J is evaluated exactly and the static certificate of
   :func:`~elastoplast.bounds.static.certify_static` checks it.

The plastic part of J is never under-estimated: ``eta`` is linear on each sub-element
and at least ``vm(tau) - sigma_y`` there (both sides are convex along the piece and
agree at its vertices), so the pair is plastically admissible everywhere and
``int eta^2 / 2H`` is integrated exactly."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from elastoplast.bounds.local.equilibrate import (average_moments, element_nodal_forces, element_tractions,
                                            facet_tractions, mesh_faces, star_moments)
from elastoplast.bounds.local.lift import IN_PLANE, element_maps, lift, mandel_to_tensor, split_mesh, tensor_to_mandel
from elastoplast.bounds.static import (CERTIFY_TOL, LocalTerms, StaticField, certify_static,
                                       local_terms, mass_matrix, psi_weights)
from elastoplast.errors import InputError, expect
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import von_mises
from elastoplast.limits import release_freed_memory
from elastoplast.mesh.topology import locate_rows


@dataclass(frozen=True)
class SplitDiscretization:
    """The discretisation of the barycentric split (:func:`~elastoplast.bounds.local.lift.split_mesh`)
    that the local field lives on: ``disc`` (only its mesh, facet groups, material and
    force are used: what :func:`certify_static` and :func:`local_terms` read) and
    ``parent (n (d+1),)`` the element of the original mesh of each sub-element."""

    disc: Discretization
    parent: np.ndarray


def split_discretization(disc: Discretization) -> SplitDiscretization:
    mesh = split_mesh(disc.mesh)
    d = disc.dim
    volumes = np.repeat(disc.volumes / (d + 1), d + 1)  # the barycentric split has equal volumes
    sd = replace(disc, problem=replace(disc.problem, mesh=mesh), volumes=volumes, grads=None, B=None)
    return SplitDiscretization(sd, np.repeat(np.arange(disc.n_elements), d + 1))


def in_plane_stress(disc: Discretization, sigma: np.ndarray) -> np.ndarray:
    """Tensors ``(n, d, d)`` of the in-plane part of Mandel stresses ``sigma (n, k)``."""
    return mandel_to_tensor(np.asarray(sigma)[:, IN_PLANE[disc.dim]], disc.dim)


@dataclass(frozen=True)
class LocalField:
    """The local field (module docstring) and how it was obtained: ``split``, ``field``
    (a :class:`StaticField` of ``split.disc``), ``star_residual`` the largest relative row
    residual of the star systems, ``imbalance`` the largest element imbalance of the
    tractions before and after the round-off repair (relative, :func:`~elastoplast.bounds.local.energy.element_imbalance`;
    zeros without sweeps) and False (no whole-mesh projection: kept for the callers), ``timings``."""

    split: SplitDiscretization
    field: StaticField
    star_residual: float
    timings: dict
    imbalance: tuple = (0.0, 0.0, False)


def restore_load(t: np.ndarray, measure: np.ndarray, cf: np.ndarray, F: float) -> None:
    """Scale the pressure ``t[cf, :, d-1]`` of the Γ0 facets (``measure``) so that ``int lam = F``
    again, in place. The rings' corrections carry no net force, but the descent resets the
    pressures it holds at zero to their old values, and its projected step moves them by the
    round-off of the projection: on an adaptively refined cylinder mesh (11,394 triangles) the
    sweeps left int lam within 2e-16 of F and one descent step 2e-12 off, twice the
    certificate's tolerance. A positive factor keeps ``lam >= 0``; the elements next to Γ0
    are left out of balance by as little, which the ring repair after it removes."""
    d = t.shape[2]
    total = float(measure @ t[cf, :, d - 1].mean(axis=1))
    if total > 0:
        t[cf, :, d - 1] *= F / total


def equilibrated_field(disc: Discretization, sigma: np.ndarray, contact_force: np.ndarray,
                       n_sweeps: int = 0, progress=None, descent: int = 0, upper: float | None = None) -> LocalField:
    """Steps 1-3 and 5 of the module docstring from the discrete stresses ``sigma (n, k)``
    in nodal balance with the contact forces ``contact_force`` (per contact node);
    ``n_sweeps`` ring sweeps, then at most ``descent`` steps over all rings together
    (step 4; both need ``n_sweeps > 0``; ``upper``: :func:`~elastoplast.bounds.local.descent.frame_descent`'s)."""
    t0 = time.perf_counter()
    timings = {}
    d, m = disc.dim, disc.material
    mesh = disc.mesh
    topo = disc.facet_topology
    maps = element_maps(mesh.points, mesh.cells)
    faces = mesh_faces(mesh.cells, topo, maps.facet_areas)
    S = in_plane_stress(disc, sigma)
    grads = disc.grads
    normals = -grads / np.linalg.norm(grads, axis=2, keepdims=True)
    n_if = faces.n_interior
    cf = n_if + topo.contact_index  # facet ids of Γ0
    from elastoplast.bounds.local.contact import contact_pressure_and_correction

    lam, dS = contact_pressure_and_correction(disc, faces, S, contact_force)
    S = S + dS
    timings["contact"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    Q = element_nodal_forces(S, disc.volumes, grads)
    target = average_moments(faces, S, normals, disc.n_elements)
    known = np.zeros_like(target)
    known[cf, :, d - 1] = (faces.measure[cf, None] * (lam @ mass_matrix(d - 1)))
    sol = star_moments(mesh.cells, faces, Q, target, known)
    t = facet_tractions(faces, sol.moments)
    star_residual = sol.residual
    del sol, Q, target, known, S, normals  # the size of a few fields each: not needed from here on
    release_freed_memory()  # and their pages: each phase below peaks on its own temporaries (limits)
    timings["equilibrate"] = time.perf_counter() - t1
    repair = (0.0, 0.0, False)
    report = progress if progress is not None else (lambda fraction, what: None)
    report(0.1, "equilibrated tractions")
    if n_sweeps > 0:
        from elastoplast.bounds.local.state import sweep_state
        from elastoplast.bounds.local.sweeps import REPAIR_PASSES, REPAIR_TOL, ring_repair, ring_sweep
        from elastoplast.bounds.local.rings import mesh_rings, ring_batches

        t1 = time.perf_counter()
        free = faces.unknown.copy()
        free[cf, d - 1] = True  # the contact pressure moves with the rings (kept >= 0, int lam = F kept)
        psi_face = np.zeros((faces.nodes.shape[0], d))
        psi_face[cf] = psi_weights(disc, topo).q
        t[cf, :, d - 1] = lam  # exactly the pressure (>= 0) the moments came from, not its round-off image
        rings = mesh_rings(mesh.points, mesh.cells)
        batches = ring_batches(mesh.points, mesh.cells, grads, faces, rings, free)
        timings["rings"] = time.perf_counter() - t1
        from elastoplast.bounds.local.kernel import ring_newton

        # the first use on a machine compiles the sweeps (about half a minute, then cached): say so before the wait
        report(0.15, "patches" if ring_newton.signatures
               else "patches; loading the compiled sweeps (compiled once per machine)")
        t1 = time.perf_counter()
        offset = out_of_plane_offset(disc, sigma)

        share = 0.75 if descent <= 0 else 0.35  # of the progress bar, for the sweeps

        def swept(i):
            report(0.15 + share * i / n_sweeps, f"sweep {i} of at most {n_sweeps}")

        on_contact = np.zeros(faces.nodes.shape[0], dtype=bool)
        on_contact[cf] = True
        release_freed_memory()  # the rings' set-up temporaries
        state = sweep_state(m, maps, faces, offset, psi_face, on_contact)  # the sweeps' and the descent's
        t = ring_sweep(mesh.points, mesh.cells, maps, faces, rings, t, disc.volumes, state, batches, n_sweeps, swept)
        timings["sweeps"] = time.perf_counter() - t1
        timings["descent_steps"] = 0
        if descent > 0:
            from elastoplast.bounds.local.descent import RingFrame, frame_descent

            t1 = time.perf_counter()

            def stepped(i):
                report(0.5 + 0.4 * i / descent, f"descent step {i} of at most {descent}")

            t, timings["descent_steps"] = frame_descent(mesh.points, maps, faces, rings, t, disc.volumes, state,
                                                        RingFrame(batches, mesh.points, faces, rings, d), descent, stepped,
                                                        upper)
            timings["descent"] = time.perf_counter() - t1
        t1 = time.perf_counter()
        release_freed_memory()
        restore_load(t, faces.measure[cf], cf, disc.force)
        # the repair leaves the pressure alone (lam >= 0 stays exact): interior and prescribed-free components only
        t, before, after = ring_repair(mesh.points, mesh.cells, maps, faces, t, batches, faces.unknown, REPAIR_TOL,
                                       REPAIR_PASSES)
        repair = (before, after, False)
        lam = t[cf, :, d - 1].copy()
        timings["repair"] = time.perf_counter() - t1
        report(0.9, "repaired")
        del rings, batches, state  # the sweeps' structures: not needed for the lift, and as large as the field
    te = element_tractions(faces, t)
    contact_nodes = faces.nodes[cf]
    del t, faces  # freed before the lift and the split mesh's topology make their own temporaries
    release_freed_memory()
    t1 = time.perf_counter()
    sig = lift(maps, te)  # (n, d+1, d+1, d, d)
    del te, maps
    timings["lift"] = time.perf_counter() - t1
    split = split_discretization(disc)
    offset = np.repeat(out_of_plane_offset(disc, sigma), d + 1)[:, None]
    tau = full_mandel(disc, sig.reshape(-1, d + 1, d, d), offset)
    del sig
    release_freed_memory()
    if d == 2:
        tau = optimal_tau33(disc, tau)
    field = admissible_field(split.disc, tau, lam, contact_nodes)
    timings["total"] = time.perf_counter() - t0
    return LocalField(split, field, star_residual, timings, tuple(repair))


def element_energies(disc: Discretization, tau: np.ndarray) -> np.ndarray:
    """``(n,)``: J's element terms of sub-vertex stresses ``tau (n, d+1, d+1, k)``, ``eta`` the vertex max."""
    from elastoplast.bounds.local.energy import element_energy

    d, m = disc.dim, disc.material
    M = mass_matrix(d)
    return element_energy(tau, disc.volumes / (d + 1), np.kron(M, m.compliance(d)), M, m.yield_stress, m.hardening)


def out_of_plane_offset(disc: Discretization, sigma: np.ndarray) -> np.ndarray:
    """Plane strain: ``sigma33 - nu (sigma11 + sigma22)`` of the discrete stress per element
    (zero in 3D). The field's ``tau33 = nu (tau11 + tau22) + offset`` minimises the elastic
    energy over tau33 up to the offset, which reproduces the discrete tau33 where the field
    equals the discrete stress (a uniform plastic state is then exact)."""
    if disc.dim == 3:
        return np.zeros(disc.n_elements)
    s = np.asarray(sigma)
    return s[:, 2] - disc.material.nu * (s[:, 0] + s[:, 1])


def full_mandel(disc: Discretization, sig: np.ndarray, offset=0.0) -> np.ndarray:
    """Mandel vectors ``(..., k)`` of in-plane tensors; plane strain:
    ``tau33 = nu (tau11 + tau22) + offset`` (:func:`out_of_plane_offset`)."""
    d = disc.dim
    inp = tensor_to_mandel(sig, d)
    if d == 3:
        return inp
    out = np.zeros(inp.shape[:-1] + (4,))
    out[..., IN_PLANE[2]] = inp
    out[..., 2] = disc.material.nu * (inp[..., 0] + inp[..., 1]) + offset
    return out


#: Newton steps of :func:`optimal_tau33`
TAU33_STEPS = 8


def optimal_tau33(disc: Discretization, tau: np.ndarray, steps: int = TAU33_STEPS) -> np.ndarray:
    """Plane strain: ``tau33`` at the vertices of every (sub-)element ``tau (n, d+1, 4)`` moved
    towards the minimiser of that element's J (``tau33`` enters no equilibrium row, so the
    field stays admissible): Newton steps on ``1/2 int A tau:tau + eta^2 / 2H`` in the
    three vertex values, ``eta = max(0, vm - sigma_y)`` at the vertices; a step is kept
    only on the elements where it lowers J (the function is convex and C1 but piecewise)."""
    from elastoplast.fem.material import deviator_matrix

    m = disc.material
    M, A, Dv = mass_matrix(2), m.compliance(2), deviator_matrix(2)
    sy, H = m.yield_stress, m.hardening

    def energy(x):
        e = np.einsum("ab,eai,ij,ebj->e", M, x, A, x)
        if H > 0:
            eta = np.maximum(von_mises(x.reshape(-1, 4)).reshape(x.shape[:2]) - sy, 0.0)
            e = e + np.einsum("ab,ea,eb->e", M, eta, eta) / H
        return e

    tau = tau.copy()
    J = energy(tau)
    for _ in range(steps):
        grad = np.einsum("ab,ebj->eaj", M, tau) @ A[2]
        hess = np.broadcast_to(A[2, 2] * M, (tau.shape[0], 3, 3)).copy()
        if H > 0:
            vm = von_mises(tau.reshape(-1, 4)).reshape(tau.shape[:2])
            eta = np.maximum(vm - sy, 0.0)
            g = np.where(eta > 0, 1.5 * (tau @ Dv[2]) / np.maximum(vm, 1e-300), 0.0)
            Me = eta @ M
            grad = grad + Me * g / H
            curv = np.where(eta > 0, (1.5 * Dv[2, 2] - g ** 2) / np.maximum(vm, 1e-300), 0.0) * Me / H
            hess = hess + M * g[:, :, None] * g[:, None, :] / H + curv[:, :, None] * np.eye(3)
        trial = tau.copy()
        trial[..., 2] -= np.linalg.solve(hess, grad[..., None])[..., 0]
        Jt = energy(trial)
        better = Jt < J
        tau[better], J[better] = trial[better], Jt[better]
    return tau


def admissible_field(split_disc: Discretization, tau: np.ndarray, lam: np.ndarray, lam_nodes: np.ndarray) -> StaticField:
    """The :class:`StaticField` of the split mesh: ``eta = max(0, vm - sigma_y)`` at every
    vertex; ``lam (n_cf, d)`` given at the Γ0 facets with nodes ``lam_nodes`` (sorted),
    reordered to the split mesh's contact facets."""
    m = split_disc.material
    vm = von_mises(tau.reshape(-1, tau.shape[-1])).reshape(tau.shape[:2])
    eta = np.maximum(vm - m.yield_stress, 0.0) if m.hardening > 0 else np.zeros(tau.shape[:2])
    cfs = split_disc.facet_topology.contact_facets
    where = locate_rows(lam_nodes, cfs, split_disc.mesh.n_nodes)
    if np.any(where < 0):
        raise InputError("mesh", "the contact facets of the split mesh are not those of the mesh")
    return StaticField(tau=tau, eta=eta, contact_facets=cfs, lam=lam[where], force=float(split_disc.force))


#: sweeps of :func:`local_lower_bound` by default, per dimension (after the first, a sweep
#: visits only the rings next to a ring that moved: :data:`~elastoplast.bounds.local.sweeps.ACTIVE_SHARE`).
#: Measured (benchmarks/bounds/local.md), gap over the global program's on the same mesh:
#: 2D cylinder at 25,600 triangles 1.82 after 32 sweeps, 1.29 after 64 (1.02 after 128, a
#: separate run); 3D default problem at 12,288 tetrahedra 1.48 after 32 sweeps that revisit
#: the rings next to any gain above 5% of the mean (72 s), 1.45 after 64 that revisit only those
#: next to an above-mean gain (34 s: the 3D share of edges.ACTIVE_SHARE)
LOCAL_SWEEPS = {2: 64, 3: 64}
#: steps at most of the descent over all rings together after the sweeps
#: (:mod:`elastoplast.bounds.local.descent`; it stops earlier once its predicted decrease is below
#: :data:`~elastoplast.bounds.local.descent.DESCENT_RTOL` of J, or, given the upper bound, once it
#: gains little against the gap: frame.DESCENT_GAP_SHARE). The sweeps alone stall in plastic
#: zones. Measured with the upper bound given (as `bounds` and `adapt` run it), gap over the
#: global program's on the same mesh, 100 steps / 300: quarter sphere at 1,080 tetrahedra
#: 4.27 / 1.25 (6.7 s / 10.5 s); default 3D problem at 12,288 1.20 (100 steps) / 1.19 (113
#: steps, then the gap stop; 67 s / 70 s); cylinder at 25,600 triangles 1.03 either way (the
#: gap stop after 24 steps); a cylinder mesh after one adaptive step (6,768 triangles) 1.80 /
#: 1.17 (6.7 s / 13.8 s)
DESCENT_STEPS = {2: 300, 3: 300}


def local_sweeps(dim: int) -> int:
    """The default number of sweeps of :func:`local_lower_bound` in dimension ``dim``."""
    return LOCAL_SWEEPS[dim]


def local_lower_bound(disc: Discretization, solution, n_sweeps: int | None = None, *, descent: int | None = None,
                      progress=None, upper: float | None = None):
    """The certified lower bound ``-J <= Pi*`` of the locally built field (module
    docstring) from a P1 ``solution`` of ``disc`` (its stresses and contact forces), as a
    :class:`~elastoplast.bounds.lower.LowerBound`: ``field`` lives on the split mesh,
    ``local`` holds the terms summed over each element's sub-elements (so that
    :func:`~elastoplast.bounds.bracket.combine` pairs it with an upper bound of ``disc``),
    ``solver`` is ``"local"``. Needs H > 0 (with H = 0 no local construction is known to
    stay within the yield surface: use :func:`~elastoplast.bounds.lower.solve_lower_bound`).
    ``n_sweeps`` ring sweeps (default :func:`local_sweeps` of the dimension), then at most
    ``descent`` steps over all rings together (default :data:`DESCENT_STEPS`; 0: none; with
    ``upper``, the upper bound's Pi on ``disc``, it stops once it gains little against the
    gap: :func:`~elastoplast.bounds.local.descent.frame_descent`). ``progress``, if given, is called as
    ``progress(fraction, what)`` after each phase, sweep and step (fraction in [0, 1])."""
    from elastoplast.bounds.lower import LowerBound
    from elastoplast.certificate.solution import Solution, Status

    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    expect(solution, Solution, "solution", "ep.solve(disc)")
    if not disc.material.hardening > 0:
        raise InputError("material.hardening", "the local lower bound needs H > 0 (any admissible stress then "
                         "bounds); with H = 0 use the global program (solve_lower_bound)")
    if np.shape(solution.sigma) != (disc.n_elements, disc.k):
        raise InputError("solution", "is the solution of another mesh")
    if descent is None:
        descent = DESCENT_STEPS[disc.dim]
    if n_sweeps is None:
        n_sweeps = local_sweeps(disc.dim)
    report = progress if progress is not None else (lambda fraction, what: None)
    t0 = time.perf_counter()
    from elastoplast.linalg.amg import one_blas_thread

    with one_blas_thread():  # small dense blocks: a second BLAS thread spin-waits for a busy core (measured 10x slower)
        lf = equilibrated_field(disc, solution.sigma, solution.contact_force, n_sweeps, progress=report,
                                descent=descent, upper=upper)
    sd = lf.split.disc
    release_freed_memory()
    t1 = time.perf_counter()
    psi = psi_weights(sd, sd.facet_topology)
    cert = certify_static(sd, lf.field, CERTIFY_TOL)
    sub = local_terms(sd, lf.field, psi, sd.facet_topology)
    n, d1 = disc.n_elements, disc.dim + 1
    local = LocalTerms(element_energy=sub.element_energy.reshape(n, d1).sum(axis=1),
                       element_stress=sub.element_stress.reshape(n, d1, -1).sum(axis=1),
                       facet_force=sub.facet_force, facet_psi_work=sub.facet_psi_work)
    J = float(sub.element_energy.sum() + sub.facet_psi_work.sum())
    timings = dict(lf.timings, certify=time.perf_counter() - t1, total=time.perf_counter() - t0)
    certified = cert.passed and psi.rigorous
    report(1.0, "certified" if certified else "not certified")
    steps = lf.timings.get("descent_steps", 0)
    msg = [f"local field: equilibration, exact lift, {n_sweeps} sweep(s)"
           + (f", {steps} descent step(s) over all rings" if steps else "")
           + f"; star residual {lf.star_residual:.1e}"
           + (f"; element imbalance {lf.imbalance[0]:.1e} repaired to {lf.imbalance[1]:.1e}"
              + " (ring passes)" if n_sweeps else "")]
    if not cert.passed:
        msg.append(f"NOT certified: {', '.join(f'{k} {getattr(cert, k):.1e}' for k in cert.failed)} above {cert.tol:.0e}")
    if not psi.rigorous:
        msg.append(f"NOT certified: obstacle term is the {psi.method}")
    return LowerBound(field=lf.field, J=J, certified=certified, certificate=cert, status=Status.CONVERGED,
                      message="; ".join(msg), timings=timings, local=local, psi_method=psi.method,
                      J_solver=float("nan"), iterations=n_sweeps, repair_residual=lf.star_residual, solver="local")
