"""elastoplast: reference solutions of C. Johnson's elasto-plastic contact problem.

The data flows mesh -> discretisation -> solver -> certificate -> output::

    import elastoplast as ep
    problem = ep.load_problem("problems/cylinder_2d.toml")
    disc = ep.discretize(problem)
    sol = ep.solve(disc, method="conic")
    print(sol.U, sol.kkt.worst)
"""

from .bounds import (Bounds, UpperBound, choose_delta, combine, energy_bounds, hencky_energy_density, penetration_bound,
                     u_bracket, upper_bound)
from .certificate import KKTResiduals, certify
from .conic import ConicOptions, solve_conic, solve_conic_cvxpy, solve_conic_displacement
from .discretize import Discretization, discretize
from .equilibrium import (LowerBound, LowerBoundOptions, StaticCertificate, StaticField, certify_static, dual_energy,
                          solve_lower_bound, static_limit_load)
from .errors import InputError
from .limit import KinematicBound, LimitBracket, LimitOptions, kinematic_limit_load, limit_load
from .material import Material, return_mapping, von_mises
from .mesh import Mesh, read_mesh, structured_mesh
from .problem import Boundary, Obstacle, Problem, load_problem, make_material, problem_from_dict
from .solution import Solution, Status, make_solution, summary
from .newton import NewtonOptions, solve_newton
from .solvers import METHODS, solve
from .uzawa import UzawaOptions, load_sweep, solve_uzawa

__version__ = "0.1.0"

__all__ = [
    "Boundary", "ConicOptions", "Discretization", "InputError", "KKTResiduals", "METHODS", "Material", "Mesh",
    "NewtonOptions", "Obstacle", "Problem", "Solution", "Status", "UzawaOptions", "certify", "discretize",
    "load_problem", "load_sweep", "make_material", "make_solution", "problem_from_dict", "read_mesh",
    "return_mapping", "solve", "solve_conic", "solve_conic_cvxpy", "solve_conic_displacement", "solve_newton",
    "solve_uzawa", "structured_mesh", "summary", "von_mises",
    "LowerBound", "LowerBoundOptions", "StaticCertificate", "StaticField", "certify_static", "dual_energy",
    "solve_lower_bound", "static_limit_load",
    "Bounds", "UpperBound", "choose_delta", "combine", "energy_bounds", "hencky_energy_density", "penetration_bound",
    "u_bracket", "upper_bound", "KinematicBound", "LimitBracket", "LimitOptions", "kinematic_limit_load", "limit_load",
]
