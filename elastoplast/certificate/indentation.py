"""Indentation figures of a solution: contact radius with its uncertainty, contact
pressures, the plastic zone and the surface profile (docs/indentation.md).

Every figure is read off the certified solution's own fields: ``active`` (contact
nodes whose force exceeds :data:`~elastoplast.certificate.solution.ACTIVE_FORCE_SHARE`
= 1e-4 of the largest nodal force: a grazing node carrying 1e-9 of the peak is free),
``plastic`` (elements whose von Mises stress reaches
:data:`~elastoplast.certificate.solution.PLASTIC_SHARE` of sigma_y + xi: on the yield
surface, where the plastic strain may grow), ``contact_pressure`` and ``u``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from elastoplast.certificate.solution import ACTIVE_FORCE_SHARE, PLASTIC_SHARE, Solution, check_solution
from elastoplast.fem.discretize import Discretization
from elastoplast.mesh.topology import boundary_facets

#: the obstacles with a radius whose contact depth is a^2 / (2R) (a paraboloid's, a sphere's to leading order)
CURVED = ("sphere", "cylinder", "paraboloid")


def symmetry_share(disc: Discretization) -> float:
    """The share of the whole contact the model holds: 1/2 for each in-plane axis along
    which the obstacle's centre lies on the edge of the contact zone (a symmetry plane
    through the axis, as on the graded generator's blocks), else 1."""
    xp = disc.mesh.points[disc.contact_nodes, :-1]
    centre = np.asarray(disc.problem.obstacle.center, dtype=float)
    if centre.size != xp.shape[1]:
        return 1.0
    tol = 1e-9 * max(float(np.ptp(xp)), 1.0)
    on_edge = (np.abs(centre - xp.min(axis=0)) <= tol) | (np.abs(centre - xp.max(axis=0)) <= tol)
    return float(0.5 ** int(on_edge.sum()))


def surface_nodes(disc: Discretization) -> np.ndarray:
    """Nodes of the boundary facets lying on the contact plane x_d = 0 (contact zone and free surface)."""
    mesh = disc.mesh
    facets = boundary_facets(np.asarray(mesh.cells))
    z = mesh.points[:, -1]
    tol = 1e-9 * float(np.abs(mesh.points).max())
    flat = facets[np.all(np.abs(z[facets]) <= tol, axis=1)]
    return np.unique(flat)


def indentation_summary(disc: Discretization, sol: Solution, *, axisymmetric: bool = False,
                        force: float | None = None) -> dict[str, Any]:
    """The indentation figures (keys below, lengths in the problem's units).

    - ``contact_radius_active``, ``contact_radius_free``: the radius (half-width in
      plane strain) of the outermost active contact node and of the nearest free
      contact node beyond it (inf when every contact node is active: the zone is
      too small); the true contact edge lies between them;
    - ``peak_contact_pressure``; ``mean_contact_pressure`` p_m = F / A with F the whole
      indenter force and A = pi a^2 (3D, axisymmetric) or 2a (plane strain, per unit
      length), a the bracket's midpoint; on a symmetric model (``symmetry_share`` < 1)
      F is the model's force divided by its share; ``mean_contact_pressure_range``:
      p_m at the bracket's two ends;
    - ``plastic_zone_depth``, ``plastic_zone_radius``: the largest depth x_d and
      in-plane distance from the obstacle centre over the centroids of plastic
      elements (0 when none is plastic);
    - ``pile_up``: the largest uplift -u_d of a free surface node outside the
      contact (toward the indenter; 0 for sink-in), ``sink_in_at_edge``: u_d at the
      outermost active node over U; for a sphere, cylinder or paraboloid of radius R,
      ``contact_depth_ratio`` c^2 = a^2 / (2 R U) (1/2 for Hertz, > 1 with pile-up).

    ``force``: the model's force that ``sol`` carries (default ``disc.force``); a
    loading path's state after a step other than its largest passes that step's force.
    """
    check_solution(disc, sol, "sol")
    r = disc.contact_radii()
    active = np.asarray(sol.active, dtype=bool)
    out: dict[str, Any] = {"active_force_share": ACTIVE_FORCE_SHARE, "plastic_share": PLASTIC_SHARE}
    pressure = sol.contact_pressure[np.isfinite(sol.contact_pressure)]
    out["peak_contact_pressure"] = float(pressure.max()) if pressure.size else float("nan")
    if active.any():
        r_a = float(r[active].max())
        beyond = r[~active & (r > r_a)]
        r_f = float(beyond.min()) if beyond.size else math.inf
    else:
        r_a, r_f = 0.0, float(r.min()) if r.size else math.inf
    out["contact_radius_active"], out["contact_radius_free"] = r_a, r_f
    a = 0.5 * (r_a + r_f) if math.isfinite(r_f) else r_a
    share = 1.0 if axisymmetric else symmetry_share(disc)
    force = (disc.force if force is None else float(force)) / share
    planar = disc.dim == 2 and not axisymmetric
    area = (lambda rad: 2.0 * rad) if planar else (lambda rad: math.pi * rad * rad)
    out["symmetry_share"] = share
    out["mean_contact_pressure"] = force / area(a) if a > 0 else float("nan")
    ends = [force / area(x) if 0 < x < math.inf else float("nan") for x in (r_f, r_a)]
    out["mean_contact_pressure_range"] = ends
    out.update(_plastic_zone(disc, sol))
    out.update(_surface_profile(disc, sol, r, active, a))
    return out


def _plastic_zone(disc: Discretization, sol: Solution) -> dict[str, float]:
    """Depth and radius of the plastic elements' centroids (0, 0 when none is plastic)."""
    plastic = np.asarray(sol.plastic, dtype=bool)
    if not plastic.any():
        return {"plastic_zone_depth": 0.0, "plastic_zone_radius": 0.0}
    centroids = disc.mesh.points[disc.mesh.cells[plastic]].mean(axis=1)
    centre = np.asarray(disc.problem.obstacle.center, dtype=float)
    planar = centroids[:, :-1] - (centre if centre.size == disc.dim - 1 else 0.0)
    return {"plastic_zone_depth": float(centroids[:, -1].max()),
            "plastic_zone_radius": float(np.linalg.norm(planar, axis=1).max())}


def _surface_profile(disc: Discretization, sol: Solution, r: np.ndarray, active: np.ndarray,
                     a: float) -> dict[str, float]:
    """Pile-up outside the contact and the surface displacement at the contact edge."""
    d = disc.dim
    nodes = surface_nodes(disc)
    u_d = np.asarray(sol.u).reshape(-1, d)[:, -1]
    in_contact = disc.contact_nodes[active] if active.any() else np.zeros(0, dtype=np.int64)
    outside = np.setdiff1d(nodes, in_contact)
    uplift = float(max(0.0, (-u_d[outside]).max(initial=0.0)))
    out = {"pile_up": uplift, "sink_in_at_edge": float("nan"), "contact_depth_ratio": float("nan")}
    if active.any() and sol.U != 0:
        edge = disc.contact_nodes[active][np.argmax(r[active])]
        out["sink_in_at_edge"] = float(u_d[edge] / sol.U)
    obstacle = disc.problem.obstacle
    if obstacle.shape in CURVED and obstacle.radius and sol.U > 0 and a > 0:
        out["contact_depth_ratio"] = float(a * a / (2.0 * obstacle.radius * sol.U))
    return out
