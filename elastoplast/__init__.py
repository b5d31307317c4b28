"""elastoplast: reference solutions of C. Johnson's elasto-plastic contact problem.

The data flows mesh -> discretisation -> solver -> certificate -> output::

    import elastoplast as ep
    problem = ep.load_problem("problems/cylinder_2d.toml")
    disc = ep.discretize(problem)
    sol = ep.solve(disc, method="conic")
    print(sol.U, sol.kkt.worst)
"""

from elastoplast.bounds.bracket import Bounds, choose_delta, combine, lower_bound, u_bracket
from elastoplast.references.certified import certified_bounds, energy_bounds
from elastoplast.bounds.upper import UpperBound, hencky_energy_density, penetration_bound, upper_bound
from elastoplast.certificate.kkt import KKTResiduals, certify
from elastoplast.solvers.conic import ConicOptions, solve_conic, solve_conic_cvxpy, solve_conic_displacement
from elastoplast.fem.discretize import Discretization, discretize
from elastoplast.bounds.lower import LowerBound, LowerBoundOptions, lower_bound_kind
from elastoplast.bounds.equilibrium.bound import solve_lower_bound, static_limit_load
from elastoplast.bounds.static import StaticCertificate, StaticField, certify_static, dual_energy
from elastoplast.errors import InputError
from elastoplast.bounds.limit_load import KinematicBound, LimitBracket, LimitOptions, kinematic_limit_load, limit_load
from elastoplast.fem.material import Material, Prestate, return_mapping, von_mises
from elastoplast.mesh.base import Mesh, read_mesh, structured_mesh
from elastoplast.problem.definition import (Boundary, Obstacle, Problem, load_problem, make_material, problem_from_dict,
                                           read_toml)
from elastoplast.mesh.refinement import BisectionState, dorfler_mark, prolong_p1, refine, shape_quality
from elastoplast.certificate.solution import Solution, Status, make_solution, summary
from elastoplast.solvers.newton import NewtonOptions, solve_newton
from elastoplast.solvers.path import PathResult, PathStep, solve_path
from elastoplast.solvers.accelerated import FastOptions
from elastoplast.options import SolverOptions
from elastoplast.solvers.registry import METHODS, method_options, solve
from elastoplast.solvers.depth import DepthSolution, solve_depth, solve_depth_path
from elastoplast.solvers.uzawa import UzawaOptions, load_sweep, solve_uzawa

from elastoplast.options import MAX_ITER_CEILING, option
from elastoplast.solvers.registry import Method
from elastoplast.certificate.kkt import energy_norm_sq
from elastoplast.bounds.bracket import element_indicators
from elastoplast.adapt.loop import adapt as solve_adaptive, uniform as solve_uniform
from elastoplast.adapt.records import AdaptOptions, AdaptResult, elements_at_gap, fitted_rate
from elastoplast.io.loading_path import path_summary
from elastoplast.certificate.indentation import indentation_summary
from elastoplast.certificate.oliver_pharr import oliver_pharr
from elastoplast.plots.figures import (draw_indicator, plot_gap_curves, plot_gaps, plot_indicator, plot_path,
                                       slice_polygons, zoom_window)

from elastoplast.version import __version__ as __version__

__all__ = [
    "BisectionState", "Boundary", "ConicOptions", "Discretization", "FastOptions", "InputError", "KKTResiduals",
    "METHODS", "Material", "Mesh", "NewtonOptions", "Obstacle", "Problem", "Solution", "SolverOptions", "Status",
    "UzawaOptions", "certify", "discretize", "dorfler_mark", "load_problem", "load_sweep", "make_material",
    "make_solution", "method_options", "problem_from_dict", "prolong_p1", "read_mesh", "read_toml", "refine",
    "return_mapping", "Prestate", "DepthSolution", "solve_depth", "solve_depth_path",
    "shape_quality", "solve", "solve_conic", "solve_conic_cvxpy", "solve_conic_displacement", "solve_newton", "solve_path", "PathResult", "PathStep",
    "solve_uzawa", "structured_mesh", "summary", "von_mises",
    "LowerBound", "LowerBoundOptions", "StaticCertificate", "StaticField", "certify_static", "dual_energy",
    "solve_lower_bound", "static_limit_load", "lower_bound", "lower_bound_kind", "certified_bounds",
    "Bounds", "UpperBound", "choose_delta", "combine", "energy_bounds", "hencky_energy_density", "penetration_bound",
    "u_bracket", "upper_bound", "KinematicBound", "LimitBracket", "LimitOptions", "kinematic_limit_load", "limit_load",
    # plug-in methods (examples/plugin_method): the method record and its options' declarations
    "Method", "option", "MAX_ITER_CEILING",
    # the adaptive loop (ep.solve_adaptive: elastoplast.adapt.loop.adapt; a plain ep.adapt would hide the
    # subpackage of that name), the certificate's energy norm, loading-path summaries
    "solve_adaptive", "solve_uniform", "AdaptOptions", "AdaptResult", "elements_at_gap", "fitted_rate",
    "element_indicators", "energy_norm_sq", "path_summary",
    # indentation: the figures of summary.json's "indentation", Oliver-Pharr on a load-unload curve
    "indentation_summary", "oliver_pharr",
    # figures (elastoplast.plots: the only module importing matplotlib, lazily)
    "draw_indicator", "plot_gap_curves", "plot_gaps", "plot_indicator", "plot_path", "slice_polygons", "zoom_window",
]
