"""The method registry: one name per solver, its options, and the one way in.

A method is a :class:`Method`: a function ``run(disc, options) -> Solution`` and
its options class (a :class:`~elastoplast.options.SolverOptions`). Besides the
built-in :data:`METHODS`, a name may be ``package.module:object`` or the name of
an entry point of the group ``elastoplast.methods``: a method from outside the
package, loaded by :func:`get_method` (:mod:`elastoplast.solvers.plugins`) and
certified like the others. Every entry
point builds options through :func:`method_options`, so a command-line flag, a
``[solver]`` table, a campaign axis and ``solve(disc, method, **options)`` are
checked alike: an unknown option, or one the method does not have (``rho`` for
``newton``), or a value out of range is an
:class:`~elastoplast.errors.InputError` naming it.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any, Callable, Mapping

from elastoplast.certificate.solution import Solution
from elastoplast.errors import InputError, expect, short_repr
from elastoplast.fem.discretize import Discretization, check_hencky
from elastoplast.fem.locking import check_hardening_carries_load, check_perfect_plasticity
from elastoplast.options import SolverOptions
from elastoplast.solvers.accelerated import FastOptions, solve_accelerated
from elastoplast.solvers.conic import (
    ConicOptions,
    solve_conic,
    solve_conic_cvxpy,
    solve_conic_displacement,
)
from elastoplast.solvers.newton import NewtonOptions, solve_newton
from elastoplast.solvers.plugins import (
    SPEC_FORM,
    check_function,
    entry_points,
    find_entry_point,
    guarded,
    import_object,
    is_spec,
    judged,
    load_entry_point,
)
from elastoplast.solvers.uzawa import UzawaOptions, check_rho, solve_uzawa


@dataclass(frozen=True)
class Method:
    """A registered solver: ``run(disc, options)`` with ``options`` an instance of ``options``."""

    name: str
    run: Callable[[Discretization, SolverOptions], Solution]
    options: type[SolverOptions]
    summary: str
    #: checks of the options that depend on the problem (e.g. Uzawa's step against the material)
    check: Callable[[Discretization, SolverOptions], None] | None = None


def _check_uzawa(disc: Discretization, options: SolverOptions) -> None:
    if options.rho is not None:
        check_rho(options.rho, disc.material)


METHODS: dict[str, Method] = {m.name: m for m in (
    Method("conic", solve_conic, ConicOptions, "stress form (S) assembled for Clarabel, Newton-polished"),
    Method("conic-cvxpy", solve_conic_cvxpy, ConicOptions, "the same model written in CVXPY"),
    Method("conic-displacement", solve_conic_displacement, ConicOptions, "displacement form (D) in CVXPY"),
    Method("uzawa", solve_uzawa, UzawaOptions, "the paper's Uzawa iteration", _check_uzawa),
    Method("uzawa-fast", solve_accelerated, FastOptions, "FISTA with restart (or ALG2) on Uzawa's steps"),
    Method("newton", solve_newton, NewtonOptions, "projected semismooth Newton on (D)"),
)}

DEFAULT_METHOD = "conic"


#: the conic methods factor the KKT matrix of an interior point; beyond these sizes
#: (elements by dimension) they cannot finish on a machine like the one the package is
#: developed on (2 cores, 24 GB, shared). Measured in benchmarks/scale (REPORT.md,
#: "Conic reference"): 3D 10 s, 34 s, 99 s wall and 0.23, 0.42, 0.90 GB at 12k, 24k,
#: 53k tetrahedra, time ~ n^1.56 and memory ~ n^1.13, extrapolated to 10 minutes at
#: about 167k and to 6 GB at about 300k; 2D (cylinder_2d) 1.6 s and 11 s at 6.4k
#: and 25.6k triangles, ~ n^1.36, 10 minutes at about 500k. The limits keep a margin
#: below those extrapolations; beyond them newton and uzawa run on the iterative path.
CONIC_MAX_ELEMENTS = {2: 400_000, 3: 150_000}


#: a mean contact pressure above this many Young's moduli has no small-strain meaning
#: and takes the arithmetic toward overflow
MAX_PRESSURE_OVER_E = 1e3


def check_solvable(disc: Discretization, method: str, options: SolverOptions | None = None) -> None:
    """Refuse, before any work, a problem ``method`` cannot answer faithfully
    (with ``options``, also options that do not suit the problem): perfect
    plasticity on a mesh that locks, an absurd force, a hardening that cannot
    carry the force within small strains on a mesh that locks
    (:func:`~elastoplast.fem.locking.check_hardening_carries_load`), a mesh too
    large for the conic reference."""
    check_perfect_plasticity(disc)
    area = float(disc.contact_area.sum())
    if area > 0 and disc.force / area > MAX_PRESSURE_OVER_E * disc.material.E:
        raise InputError("load.force", f"{disc.force:g} over the contact zone's area {area:g} is a mean pressure of "
                                       f"{disc.force / area:.3g}, above {MAX_PRESSURE_OVER_E:g} E: far outside small "
                                       "strains")
    check_hardening_carries_load(disc)
    limit = CONIC_MAX_ELEMENTS[disc.dim]
    if method in METHODS and method.startswith("conic") and disc.n_elements > limit:
        fast = [m for m in METHODS if not m.startswith("conic")]
        raise InputError("method", f"{disc.n_elements:,} elements is beyond what the conic reference can finish "
                                   f"here (at most {limit:,} in {disc.dim}D, measured: benchmarks/scale); "
                                   f"use one of {fast}")
    m = get_method(method)
    if options is not None and m.check is not None:
        m.check(disc, options)


def get_method(name: Any, field: str = "method") -> Method:
    """The method ``name``, or an InputError naming ``field``: a built-in name (a key
    of :data:`METHODS`, which always wins), ``package.module:object``, or the name of
    an entry point of the group ``elastoplast.methods``. A method from outside is
    loaded at each call (the import system caches its module) and comes back as a
    :class:`Method` called ``name`` whose run is certified and judged by the
    package (:func:`~elastoplast.solvers.plugins.judged`)."""
    if isinstance(name, str) and name in METHODS:
        return METHODS[name]
    if not isinstance(name, str) or not name.strip():
        raise InputError(field, f"unknown method {short_repr(name)} (choose from {sorted(METHODS)}, or give "
                                f"{SPEC_FORM})")
    if is_spec(name):
        return plugin_method(import_object(name, field), name, field)
    entry = find_entry_point(name, METHODS, field)
    if entry is None:
        plugins = sorted(entry_points(METHODS))
        installed = f", the installed {plugins}" if plugins else ""
        raise InputError(field, f"unknown method {name!r} (choose from {sorted(METHODS)}{installed}, or give "
                                f"{SPEC_FORM})")
    return plugin_method(load_entry_point(entry, field), name, field, f"entry point {name!r} ({entry.value})")


def plugin_method(obj: Any, name: str, field: str, where: str = "") -> Method:
    """A method from outside as a :class:`Method` called ``name``: ``obj`` is a
    Method (its options class and check are kept) or a function ``run(disc,
    options)``, which takes the base :class:`~elastoplast.options.SolverOptions`.
    Either way its run is wrapped by :func:`~elastoplast.solvers.plugins.judged`.
    Anything else is an InputError naming ``field``."""
    where = where or repr(name)
    if isinstance(obj, Method):
        if not (isinstance(obj.options, type) and issubclass(obj.options, SolverOptions)):
            raise InputError(field, f"{where} is a Method whose options {short_repr(obj.options)} are not a class "
                                    "deriving from elastoplast.options.SolverOptions")
        check_function(obj.run, f"{where}'s run", field)
        return Method(name, judged(obj.run, name), obj.options, obj.summary or f"from {where}",
                      guarded(obj.check, name))
    if callable(obj) and not isinstance(obj, type):
        check_function(obj, where, field)
        doc = (inspect.getdoc(obj) or "").strip().splitlines()
        return Method(name, judged(obj, name), SolverOptions, doc[0] if doc else f"from {where}")
    raise InputError(field, f"{where} is {short_repr(obj, 60)} ({type(obj).__name__}), neither a Method "
                            "(elastoplast.solvers.registry.Method) nor a function run(disc, options)")


def method_options(method: str, values: Mapping[str, Any] | SolverOptions | None = None, *,
                   prefix: str = "") -> SolverOptions:
    """Checked options of ``method`` from a mapping (or an options object of its class)."""
    m = get_method(method, f"{prefix}method" if prefix else "method")
    if isinstance(values, SolverOptions):
        if not isinstance(values, m.options):
            raise InputError(f"{prefix}options", f"method {method!r} takes {m.options.__name__}, "
                                                 f"got {type(values).__name__}")
        return values
    return m.options.build(values, method=method, prefix=prefix)


def solver_settings(section: Mapping[str, Any], prefix: str = "solver") -> tuple[str, dict[str, Any]]:
    """``(method, options)`` from a ``[solver]`` table: the method and the
    options given for it, checked (errors name ``prefix.key``)."""
    if not isinstance(section, Mapping):
        raise InputError(prefix, f"must be a table, got {section!r}")
    values = dict(section)
    method = values.pop("method", DEFAULT_METHOD)
    opts = method_options(method, values, prefix=f"{prefix}.")
    return method, {k: getattr(opts, k) for k in values}


def solve(disc: Discretization, method: str = DEFAULT_METHOD, options: SolverOptions | None = None,
          **values: Any) -> Solution:
    """Solve (2.1) by ``method`` (a key of :data:`METHODS`, ``package.module:object``
    or an entry point's name: :func:`get_method`), with options given
    either as an options object or as keywords (not both). Whatever the method, an
    answer whose strains leave the small-strain model is not ``converged``: every
    answer is built by :func:`~elastoplast.certificate.solution.make_solution`, which
    judges its strains."""
    expect(disc, Discretization, "disc", "ep.discretize(problem)")
    refuse_depth_control(disc, "ep.solve")
    if disc.problem.path is not None:  # a step (state set) is Hencky-shaped and solved here; a whole path is not
        check_hencky(disc, "ep.solve")
    m = get_method(method)
    opts = given_options(method, options, values)
    check_solvable(disc, m.name, opts)
    return m.run(disc, opts)


def refuse_depth_control(disc: Discretization, where: str) -> None:
    """An :class:`InputError` naming ``load.displacement`` when ``disc`` prescribes the
    rigid body's displacement: its force is unknown, and ``disc.force`` is only the
    root search's first guess, so a force-controlled solve would answer another problem."""
    if disc.problem.depth_controlled:
        raise InputError("load.displacement", f"{where} solves under a given force; this problem prescribes the "
                                              "displacement: use ep.solve_depth (or ep.solve_depth_path)")


def given_options(method: str, options: SolverOptions | None, values: Mapping[str, Any]) -> SolverOptions:
    """The checked options of ``method`` given as an options object or as keywords
    (not both), as :func:`solve` and :func:`~elastoplast.solvers.path.solve_path` take them."""
    if options is not None and values:
        raise InputError("options", "give an options object or keyword options, not both")
    return method_options(method, options if options is not None else values)
