"""Discrete operators of (2.1): P1 displacements, P0 stresses (docs/math.md).

Everything is vectorised over elements; each global operator is one sparse build.
Degrees of freedom are numbered ``node * d + component``; ``free`` lists the
ones not fixed by a Dirichlet condition and every operator acts on those.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from elastoplast.limits import check_mesh_size
from elastoplast.errors import InputError, expect
from elastoplast.fem.assembly import (
    HOOP_ROW,
    STRAIN_ROWS,
    Layout,
    ScalarView,
    assemble,
    element_geometry,
    element_layout,
    rigid_motions,
    scalar_view,
)
from elastoplast.fem.axisymmetry import axis_nodes, check_meridian_mesh, ring_contact_area, ring_weights
from elastoplast.fem.material import Material, Prestate, n_components
from elastoplast.mesh.base import Mesh
from elastoplast.mesh.topology import FacetTopology, boundary_facets, facet_topology
from elastoplast.problem.definition import Boundary, Problem
from elastoplast.mesh.base import read_only


def sealed_matrix(m: sp.csr_matrix) -> sp.csr_matrix:
    """A CSR matrix sharing ``m``'s arrays through read-only views (``m`` itself untouched;
    anything that is not a sparse matrix, as a test's stand-in, as it is)."""
    if not sp.issparse(m):
        return m
    m = m.tocsr()
    if not (m.data.flags.writeable or m.indices.flags.writeable or m.indptr.flags.writeable):
        return m  # sealed already
    out = sp.csr_matrix(m.shape, dtype=m.dtype)
    out.data, out.indices, out.indptr = read_only(m.data), read_only(m.indices), read_only(m.indptr)
    out.has_canonical_format = m.has_canonical_format
    return out


@dataclass(frozen=True)
class Discretization:
    """The data of the discrete problem (2.1) for one :class:`Problem`.

    ``B`` maps free dofs to element strains stacked element by element
    (``(n_el * k, n_free)``), ``volumes`` are ``|T|`` and ``grads`` the shape
    function gradients ``(n_el, d+1, d)`` B is made of, ``N`` picks the vertical
    dof of each contact node (``(n_contact, n_free)``), ``psi`` is the obstacle
    at the contact nodes and ``contact_area`` their lumped share of the flat
    boundary ``x_d = 0`` (used only to turn forces into pressures).

    In an axisymmetric model (``problem.axisymmetric``) ``volumes`` are the element
    weights ``2 pi |T| r_T``, ``hoop`` the reciprocal centroid radii ``1 / r_T`` that
    make B's hoop row, and ``contact_area`` the consistent ring areas
    (:mod:`elastoplast.fem.axisymmetry`); ``hoop`` is None otherwise.

    ``state`` is None for Hencky's problem (2.1). A step of a loading path
    (:meth:`step`) carries the material state it starts from; its unknowns are
    then the displacement increment, and ``psi`` is the gap the increment sees.
    """

    problem: Problem
    volumes: np.ndarray
    grads: np.ndarray
    B: sp.csr_matrix
    free: np.ndarray
    fixed: np.ndarray
    contact_nodes: np.ndarray
    N: sp.csr_matrix
    psi: np.ndarray
    contact_area: np.ndarray
    state: Prestate | None = None
    hoop: np.ndarray | None = None
    #: the obstacle itself at the contact nodes when ``psi`` is a step's gap (:meth:`step`)
    obstacle_psi: np.ndarray | None = None
    #: the data derived from the mesh, its facet groups and the element geometry alone,
    #: shared by every Discretization with the same ones (:meth:`with_force`, :meth:`step`)
    shared: "SharedOperators | None" = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.seal()
        if self.shared is None or not self.shared.serves(self):
            object.__setattr__(self, "shared", SharedOperators(self.mesh, self.problem.boundary, self.grads,
                                                               self.volumes, self.free, self.hoop))

    def __setstate__(self, state: dict) -> None:
        """Unpickled (or copied): the arrays read-only again (pickle drops the flag)."""
        self.__dict__.update(state)
        self.seal()

    def seal(self) -> None:
        """Make every array of the discrete problem a read-only view, the sparse
        operators' ``data``, ``indices`` and ``indptr`` included: a method that
        edits them in place fails at once instead of solving (and being judged
        against) another problem."""
        for name in ("volumes", "grads", "free", "fixed", "contact_nodes", "psi", "contact_area"):
            object.__setattr__(self, name, read_only(getattr(self, name)))
        for name in ("B", "N"):
            object.__setattr__(self, name, sealed_matrix(getattr(self, name)))
        if self.hoop is not None:
            object.__setattr__(self, "hoop", read_only(self.hoop))

    @property
    def mesh(self) -> Mesh:
        return self.problem.mesh

    @property
    def material(self) -> Material:
        return self.problem.material

    @property
    def dim(self) -> int:
        return self.problem.mesh.dim

    @property
    def measure_dim(self) -> int:
        """The dimension of the element measure: 3 in an axisymmetric model (its
        weights are volumes of rings), the mesh's dimension otherwise."""
        return 3 if self.problem.axisymmetric else self.dim

    @property
    def k(self) -> int:
        return n_components(self.dim)

    @property
    def n_elements(self) -> int:
        return self.volumes.size

    @property
    def n_free(self) -> int:
        return self.free.size

    @property
    def n_contact(self) -> int:
        return self.contact_nodes.size

    @property
    def force(self) -> float:
        return self.problem.force

    @property
    def facet_topology(self) -> FacetTopology:
        """The mesh's facets classified by the problem's facet groups (:func:`facet_topology`), built once."""
        return self.shared.facet_topology

    @property
    def length_scale(self) -> float:
        """Largest extent of the body."""
        pts = self.mesh.points
        return float(np.max(pts.max(axis=0) - pts.min(axis=0)))

    def strain(self, u_free: np.ndarray) -> np.ndarray:
        """Element strains ``(n_el, k)`` of free-dof displacements."""
        return (self.B @ u_free).reshape(self.n_elements, self.k)

    def internal_force(self, sigma: np.ndarray) -> np.ndarray:
        """``r = sum_T |T| B_T^T sigma_T`` on the free dofs."""
        return self.B.T @ (sigma * self.volumes[:, None]).ravel()

    @property
    def layout(self) -> Layout:
        """The block pattern of the stiffness-type matrices over every dof
        (:func:`~elastoplast.fem.assembly.element_layout`), built once."""
        return self.shared.layout

    @property
    def free_view(self) -> ScalarView:
        """Their CSR pattern on the free dofs (:func:`~elastoplast.fem.assembly.scalar_view`), built once."""
        return self.shared.free_view

    def weighted_gram(self, M: np.ndarray) -> sp.csr_matrix:
        """``sum_T |T| B_T^T M_T B_T`` on the free dofs, for one ``M (k, k)`` shared by
        every element (Uzawa's metric with M = I, the elastic stiffness with M = C)
        or one per element, ``M (n_el, k, k)`` (the tangent stiffness)."""
        view = self.free_view
        return view.csr(view.from_blocks(assemble(self.layout, M)))

    def full_displacement(self, u_free: np.ndarray) -> np.ndarray:
        """Nodal displacements ``(n_nodes, d)`` with zeros at fixed dofs."""
        u = np.zeros(self.mesh.n_nodes * self.dim)
        u[self.free] = u_free
        return u.reshape(-1, self.dim)

    def free_displacement(self, u: np.ndarray) -> np.ndarray:
        return np.asarray(u, dtype=float).reshape(-1)[self.free]

    def contact_radii(self) -> np.ndarray:
        """Distance of each contact node from the obstacle centre in the plane."""
        xp = self.mesh.points[self.contact_nodes, :-1]
        return np.linalg.norm(xp - np.asarray(self.problem.obstacle.center), axis=1)

    def step(self, force: float, state: Prestate, u_free: np.ndarray) -> "Discretization":
        """One backward-Euler step of Prandtl-Reuss' law from ``state`` and the free
        displacements ``u_free`` of the last step, to the force ``force``: the same
        operators, the state, and the obstacle shifted by the last vertical
        displacements (``psi + N u``), so that the contact conditions on the
        increment are those of the total displacement (docs/evolution.md)."""
        return replace(self.with_force(force), state=state, psi=read_only(self.base_psi + self.N @ u_free),
                       obstacle_psi=self.base_psi)

    @property
    def base_psi(self) -> np.ndarray:
        """The obstacle itself at the contact nodes (``psi`` of the problem before any step)."""
        return self.psi if self.obstacle_psi is None else self.obstacle_psi

    def with_force(self, force: float) -> "Discretization":
        """The same operators for another load (nothing is rebuilt: the mesh, its facet
        groups and the element geometry are the same, so :attr:`shared` is); ``force``
        is checked as the problem file's ``load.force`` (:meth:`Problem.with_force`) and
        against the magnitudes no solver can scale as :func:`discretize` checks it
        (:func:`check_scales`: a force of 1e-300 is refused here as in a problem file)."""
        out = replace(self, problem=self.problem.with_force(force))
        check_scales(out)
        return out


class SharedOperators:
    """What a :class:`Discretization` derives from its mesh, facet groups, element
    geometry (with an axisymmetric model's hoop rows) and free dofs alone, each built on
    first use. One instance serves every
    Discretization made from the same objects (:meth:`serves` compares them by
    identity), so a new load or a path's step reuses them and any other change of
    those inputs gets a new instance: nothing derived is ever carried by hand."""

    def __init__(self, mesh: Mesh, boundary: Boundary, grads: np.ndarray, volumes: np.ndarray, free: np.ndarray,
                 hoop: np.ndarray | None):
        self.inputs = (mesh, boundary, grads, volumes, free, hoop)

    def serves(self, disc: Discretization) -> bool:
        mine = (disc.mesh, disc.problem.boundary, disc.grads, disc.volumes, disc.free, disc.hoop)
        return all(a is b for a, b in zip(self.inputs, mine))

    @cached_property
    def facet_topology(self) -> FacetTopology:
        mesh, boundary = self.inputs[:2]
        return facet_topology(mesh, boundary)

    @cached_property
    def layout(self) -> Layout:
        mesh, _, grads, volumes, _, hoop = self.inputs
        return element_layout(mesh, grads, volumes, hoop)

    @cached_property
    def free_view(self) -> ScalarView:
        return scalar_view(self.layout, self.inputs[4])


def check_hencky(disc: Discretization, what: str) -> None:
    """Refuse a loading path where ``what`` serves Hencky's problem only: a step of a
    path (``disc.state`` set), or a problem whose file gives a path (``load.path``).
    An InputError naming ``disc``, never an answer to another problem."""
    if disc.state is not None:
        raise InputError("disc", f"is a step of a loading path (it carries a state): {what} serves Hencky's "
                                 "problem only; give the problem's discretisation (ep.discretize)")
    if disc.problem.path is not None:
        raise InputError("disc", f"is a loading path of {len(disc.problem.path)} step(s) (load.path): {what} serves "
                                 "Hencky's problem only; solve the path with ep.solve_path(disc, disc.problem.path, "
                                 "method), or give Hencky's problem at one force with disc.with_force(F)")


def free_strain_operator(mesh: Mesh, grads: np.ndarray, position: np.ndarray, chunk: int = 1 << 17,
                         hoop: np.ndarray | None = None) -> sp.csr_matrix:
    """``B`` on the free dofs (rows ``element * k + component``, Mandel), built
    row by row as CSR.

    ``position`` gives the free-dof number of every dof (-1 where fixed). Each
    row ``element * k + c`` holds the terms of :data:`STRAIN_ROWS` at the
    element's free dofs, so the CSR arrays are written directly, in chunks of
    elements, without a COO sort or a column slice: at a million tetrahedra
    this takes a few seconds and about the size of B itself, against 16 s and
    three copies. Indices are 32-bit while they fit. ``hoop`` (axisymmetric models:
    ``1 / r_T``) adds the hoop row of :func:`~elastoplast.fem.assembly.strain_matrices`.
    """
    d, n = mesh.dim, mesh.n_elements
    rows = [list(t) for t in STRAIN_ROWS[d]]
    if hoop is not None:
        rows[HOOP_ROW] = [(0, None, 1.0)]
    k, m = len(rows), d + 1
    width = max(len(t) for t in rows) * m
    n_free = int(position.max(initial=-1)) + 1
    it = np.int32 if max(n_free, n * k * width) < np.iinfo(np.int32).max else np.int64
    data, indices, counts = [], [], []
    for s in range(0, n, chunk):
        cells = mesh.cells[s:s + chunk]
        g = grads[s:s + chunk]
        cols = np.full((cells.shape[0], k, width), -1, dtype=it)
        vals = np.zeros((cells.shape[0], k, width))
        for c, terms in enumerate(rows):
            for t, (comp, der, w) in enumerate(terms):
                cols[:, c, t * m:(t + 1) * m] = position[cells * d + comp]
                vals[:, c, t * m:(t + 1) * m] = w * (g[:, :, der] if der is not None else hoop[s:s + chunk, None] / m)
        keep = cols >= 0
        data.append(vals[keep])
        indices.append(cols[keep])
        counts.append(keep.sum(axis=2).ravel())
    counts = np.concatenate(counts)
    indptr = np.zeros(counts.size + 1, dtype=it)
    np.cumsum(counts, out=indptr[1:])
    B = sp.csr_matrix((np.concatenate(data), np.concatenate(indices), indptr), shape=(n * k, n_free))
    B.sort_indices()
    return B


_MOTION_NAMES = {2: ["translation x", "translation y", "rotation in xy"],
                 3: ["translation x", "translation y", "translation z", "rotation in xy", "rotation in yz", "rotation in xz"]}


def _check_no_rigid_motion(mesh: Mesh, fixed_mask: np.ndarray, axisymmetric: bool = False) -> None:
    """Every connected piece of the mesh must have its rigid motions blocked (in an
    axisymmetric model the only one is the axial translation)."""
    d = mesh.dim
    e = mesh.cells
    pairs = np.concatenate([e[:, [i, j]] for i in range(d + 1) for j in range(i)], axis=0)
    adj = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(mesh.n_nodes,) * 2)
    n_parts, labels = connected_components(adj, directed=False)
    for part in range(n_parts):
        nodes = np.flatnonzero(labels == part)
        R = rigid_motions(mesh.points[nodes], axisymmetric)
        mask = fixed_mask.reshape(-1, d)[nodes].ravel()
        Rf = R[mask]
        scale = np.linalg.norm(R, axis=0)
        s = np.linalg.svd(Rf / scale, compute_uv=False) if Rf.size else np.zeros(0)
        rank = int(np.sum(s > 1e-8 * max(1.0, s.max(initial=0.0))))
        if rank < R.shape[1]:
            # name a free motion: the one least touched by the fixed dofs
            free_norm = np.linalg.norm(Rf / scale, axis=0) if Rf.size else np.zeros(R.shape[1])
            name = "translation y" if axisymmetric else _MOTION_NAMES[d][int(np.argmin(free_norm))]
            raise InputError(
                "boundary",
                f"the fixed displacements leave a rigid motion free ({name}"
                + (f", mesh part {part}" if n_parts > 1 else "")
                + "); clamp or fix more of the boundary",
            )


def _flat_bottom_area(mesh: Mesh, tol: float, axisymmetric: bool = False) -> np.ndarray:
    """Lumped area of the boundary lying in ``x_d = 0`` at each node (the consistent
    ring area in an axisymmetric model)."""
    d = mesh.dim
    facets = boundary_facets(mesh.cells)
    on_plane = np.all(np.abs(mesh.points[facets][:, :, -1]) <= tol, axis=1)
    facets = facets[on_plane]
    if axisymmetric:
        return ring_contact_area(mesh, facets)
    X = mesh.points[facets][:, :, :-1]  # in-plane coordinates
    if d == 2:
        meas = np.abs(X[:, 1, 0] - X[:, 0, 0])
    else:
        v1, v2 = X[:, 1] - X[:, 0], X[:, 2] - X[:, 0]
        meas = 0.5 * np.abs(v1[:, 0] * v2[:, 1] - v1[:, 1] * v2[:, 0])
    area = np.zeros(mesh.n_nodes)
    np.add.at(area, facets.ravel(), np.repeat(meas / d, d))
    return area


# ----------------------------------------------------------------------------
# input checks before anything is built (kept apart from the assembly below)
# ----------------------------------------------------------------------------


def check_mesh_arrays(mesh: Mesh) -> None:
    """A :class:`Mesh` built in Python must be what the operators expect: finite
    coordinates ``(n, 2 or 3)``, simplices ``(n_el, d+1)`` of valid node indices, and a
    size whose operators fit in memory (files and generators are checked on the way in;
    this guards meshes made directly)."""
    pts, cells = mesh.points, mesh.cells
    if pts.ndim != 2 or pts.shape[1] not in (2, 3) or cells.ndim != 2 or cells.shape[1] != pts.shape[1] + 1:
        raise InputError("mesh", f"points must be (n, 2 or 3) and cells (n_el, d + 1), got {pts.shape} and {cells.shape}")
    if cells.shape[0] == 0:
        raise InputError("mesh", "the mesh has no elements")
    check_mesh_size(mesh.dim, mesh.n_nodes, mesh.n_elements, sum(len(g) for g in mesh.groups.values()), "mesh",
                    "this mesh", "use a coarser mesh")
    if cells.dtype.kind not in "iu" or cells.min() < 0 or cells.max() >= mesh.n_nodes:
        raise InputError("mesh", f"cells must be integer node indices in [0, {mesh.n_nodes})")
    if not np.all(np.isfinite(pts)):
        raise InputError("mesh", "node coordinates must be finite")
    for name, facets in mesh.groups.items():
        facets = np.asarray(facets)
        if facets.size and (facets.ndim != 2 or facets.shape[1] != mesh.dim or facets.dtype.kind not in "iu"
                            or facets.min() < 0 or facets.max() >= mesh.n_nodes):
            raise InputError("mesh", f"group {name!r} must be ({mesh.dim}-node facets) of node indices in "
                                     f"[0, {mesh.n_nodes})")


def _vertical_fixed_message(problem: Problem, contact_nodes: np.ndarray, vertical_fixed: np.ndarray) -> str:
    """Which groups fix the vertical displacement of contact nodes."""
    mesh, bnd, d = problem.mesh, problem.boundary, problem.mesh.dim
    nodes = contact_nodes[vertical_fixed]
    names = [n for n in list(bnd.clamped) + list(bnd.fix_component.get(d - 1, ()))
             if np.intersect1d(mesh.group_nodes([n]), nodes).size]
    return (f"{int(vertical_fixed.sum())} contact node(s) have their vertical displacement fixed (by group(s) "
            f"{sorted(set(names))}): the contact zone must stay clear of clamped groups and of fix_component on the "
            "vertical axis")


def discretize(problem: Problem) -> Discretization:
    """Build the operators of (2.1) and refuse inputs that make it ill-posed."""
    expect(problem, Problem, "problem", "ep.problem_from_dict(data) or ep.load_problem(path)")
    mesh = problem.mesh
    d = mesh.dim
    check_mesh_arrays(mesh)
    extent = float(np.max(mesh.points.max(axis=0) - mesh.points.min(axis=0)))
    tol = 1e-9 * extent
    axisymmetric = problem.axisymmetric
    bnd = problem.boundary
    if axisymmetric:
        check_meridian_mesh(mesh, bnd.clamped, bnd.fix_component.get(0, ()), tol)
    volumes, grads = element_geometry(mesh)
    hoop = None
    if axisymmetric:
        volumes, hoop = ring_weights(mesh, volumes)

    fixed_mask = np.zeros((mesh.n_nodes, d), dtype=bool)
    fixed_mask[mesh.group_nodes(bnd.clamped)] = True
    for comp, names in bnd.fix_component.items():
        fixed_mask[mesh.group_nodes(names), comp] = True
    if axisymmetric:
        fixed_mask[axis_nodes(mesh, tol), 0] = True  # u_r = 0 on the axis, by symmetry
    fixed_mask = fixed_mask.ravel()

    contact_nodes = mesh.group_nodes(bnd.contact)
    if contact_nodes.size == 0:
        raise InputError("boundary.contact", f"the contact zone {list(bnd.contact)} has no nodes")
    off_plane = np.abs(mesh.points[contact_nodes, -1]) > tol
    if np.any(off_plane):
        raise InputError(
            "boundary.contact",
            f"{int(off_plane.sum())} contact node(s) are not in the contact plane x_{d} = 0 "
            "(the body must sit on x_d = 0 with the rigid body below)",
        )
    if np.any(mesh.points[:, -1] < -tol):
        raise InputError("mesh", f"part of the body lies below the contact plane x_{d} = 0")
    vertical_fixed = fixed_mask.reshape(-1, d)[contact_nodes, d - 1]
    if np.any(vertical_fixed):
        raise InputError("boundary.contact", _vertical_fixed_message(problem, contact_nodes, vertical_fixed))
    _check_no_rigid_motion(mesh, fixed_mask, axisymmetric)

    free = np.flatnonzero(~fixed_mask)
    fixed = np.flatnonzero(fixed_mask)
    position = -np.ones(mesh.n_nodes * d, dtype=np.int64)
    position[free] = np.arange(free.size)
    B = free_strain_operator(mesh, grads, position, hoop=hoop)
    cols = position[contact_nodes * d + d - 1]
    N = sp.csr_matrix((np.ones(contact_nodes.size), (np.arange(contact_nodes.size), cols)), shape=(contact_nodes.size, free.size))

    psi = problem.obstacle.psi(mesh.points[contact_nodes, :-1], field="obstacle")
    area = _flat_bottom_area(mesh, tol, axisymmetric)[contact_nodes]
    disc = Discretization(
        problem=problem,
        volumes=read_only(volumes),
        grads=read_only(grads),
        B=B,
        free=free,
        fixed=fixed,
        contact_nodes=contact_nodes,
        N=N,
        psi=read_only(psi),
        contact_area=read_only(area),
        hoop=None if hoop is None else read_only(hoop),
    )
    check_scales(disc)
    return disc


@dataclass(frozen=True)
class Units:
    """Reference magnitudes for solving in O(1) numbers.

    ``stress``: the mean pressure ``F / |Gamma_0|``; ``length``: the mean
    element size ``mean(|T|)**(1/d)``, so that element volumes are O(1) on
    average; ``displacement = length * stress / E``, so strains come in units of
    ``stress / E``; ``force = stress * length**(d-1)``. (``d`` is the dimension of the
    measure, ``Discretization.measure_dim``: 3 for the rings of an axisymmetric model.)
    """

    stress: float
    length: float
    displacement: float
    force: float
    E: float


def reference_units(disc: Discretization) -> Units:
    """The :class:`Units` of ``disc`` (their definitions are in its docstring)."""
    m, d = disc.material, disc.measure_dim
    L = float(disc.volumes.mean() ** (1.0 / d))
    area = disc.contact_area.sum()
    S = disc.force / area if area > 0 else m.E * 1e-3
    return Units(stress=S, length=L, displacement=L * S / m.E, force=S * L ** (d - 1), E=m.E)


SCALE_RANGE = (1e-100, 1e100)
#: a hardening below this share of E is zero to every solver (the working units divide by E;
#: 1/H enters the bounds), but not to the refusals of perfect plasticity: refused, use 0
MIN_HARDENING_OVER_E = 1e-12


def check_scales(disc: Discretization) -> None:
    """Refuse magnitudes no solver can scale: in the units of :class:`Units` (E = 1)
    the yield stress ``sigma_y / S``, the strain scale ``S / E`` and the obstacle
    ``psi / displacement`` must lie within ``SCALE_RANGE`` (squares then stay finite
    doubles). Beyond it (a force of 1e-300 or 1e300, E = 1e300 against a yield stress
    of 1e3) the scaled data overflow and the solvers return nan. A hardening
    ``0 < H < MIN_HARDENING_OVER_E * E`` is refused too: it is perfect plasticity to the
    arithmetic (1/H of 1e300 in the bounds' programs) while escaping what H = 0 is
    checked for."""
    lo, hi = SCALE_RANGE
    m = disc.material
    if 0 < m.hardening < MIN_HARDENING_OVER_E * m.E:
        raise InputError("material.hardening", f"{m.hardening:g} is numerically zero against E = {m.E:g} (below "
                                               f"{MIN_HARDENING_OVER_E:g} E): use 0 for perfect plasticity")
    with np.errstate(all="ignore"):
        u = reference_units(disc)
        yield_strain = m.yield_stress / m.E
        strain = u.stress / m.E
        psi = float(np.max(np.abs(disc.psi), initial=0.0)) / u.displacement
    if not lo <= yield_strain <= hi:
        field = "material.E" if abs(np.log10(m.E)) >= abs(np.log10(m.yield_stress)) else "material.yield_stress"
        raise InputError(field, f"E = {m.E:g} against yield_stress = {m.yield_stress:g}: their ratio is beyond "
                                f"[{lo:g}, {hi:g}], which no solver can scale")
    if not lo <= strain <= hi or not psi <= hi:
        raise InputError("load.force", f"force = {disc.force:g} gives a mean contact pressure F / |Gamma_0| = "
                                       f"{u.stress:.3g}, {strain:.3g} times E (and an obstacle {psi:.3g} times the "
                                       f"displacement scale): beyond [{lo:g}, {hi:g}], which no solver can scale")
    if disc.problem.path is not None and disc.state is None:
        check_path_scales(disc, disc.problem.path, "load.path")


def check_path_scales(disc: Discretization, forces, field: str) -> None:
    """Refuse, before step 1, a loading path whose smallest force is a load no solver can
    scale (:func:`check_scales` checks ``disc.force``, a path's largest): a step at 1e-300
    would be refused when the path reaches it, or run into overflow."""
    lo = SCALE_RANGE[0]
    area = disc.contact_area.sum()
    least = min(forces)
    strain = least / area / disc.material.E if area > 0 else 1.0
    if not lo <= strain:
        raise InputError(field, f"entry {list(forces).index(least) + 1}, {least:g}, gives a mean contact pressure "
                                f"{strain:.3g} times E: below {lo:g}, which no solver can scale (end an unloading "
                                "at a small force, e.g. 1e-6 of the largest)")


#: largest obstacle height, in displacement units, the solvers see (see :func:`nondimensionalize`)
PSI_CAP = 1e9


def nondimensionalize(disc: Discretization) -> tuple[Discretization, Units]:
    """The same discrete problem in the units of :class:`Units` (E becomes 1).

    Solvers may work on the result and map back with ``sigma * stress``,
    ``u * displacement``, ``contact forces * force``; the certificate is always
    evaluated on the original problem.

    The obstacle is capped at :data:`PSI_CAP` displacement units: a contact node
    whose gap is that many times the displacement scale is inactive anyway, and
    the cap keeps a tiny force (displacements of 1e-15 the obstacle's height)
    from swamping the solvers' arithmetic. The certificate, on the original
    problem, would show any penetration the cap allowed.
    """

    m, d = disc.material, disc.measure_dim
    units = reference_units(disc)
    S, L = units.stress, units.length
    material = Material(1.0, m.nu, m.yield_stress / S, m.hardening / m.E)
    problem = replace(disc.problem, material=material, force=disc.force / units.force, path=None)
    return (
        replace(
            disc,
            problem=problem,
            volumes=disc.volumes / L**d,
            grads=disc.grads * L,
            B=(disc.B * L).tocsr(),
            psi=np.minimum(disc.psi / units.displacement, PSI_CAP),
            contact_area=disc.contact_area / L ** (d - 1),
            hoop=None if disc.hoop is None else disc.hoop * L,
            state=None if disc.state is None else disc.state.scaled(S, S / m.E, units.displacement),
        ),
        units,
    )
