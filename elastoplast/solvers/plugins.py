"""Methods from outside the package: ``package.module:object`` and the ``elastoplast.methods`` entry points.

The registry (:mod:`elastoplast.solvers.registry`) resolves a method name in
this order: a built-in name; a name holding a colon, ``package.module:object``,
imported with :func:`import_object`; otherwise an entry point of the group
:data:`GROUP` (:func:`find_entry_point`, :func:`load_entry_point`). The object is
a :class:`~elastoplast.solvers.registry.Method` or a plain function
``run(disc, options)``; the registry wraps its run in :func:`judged`, so
that whatever it returns (a ``Solution``, ``(u, U)`` or ``(u, U, sigma, xi)``) is
certified by the package and given the status its certificate earns at
``options.tol`` (:func:`judge`), never the one the method claims.

Every failure to find or load a method is an :class:`~elastoplast.errors.InputError`
naming the field the name came from, in one line; a method that raises inside
its run raises :class:`PluginError` (the command line's internal-error exit), an
``InputError`` it raises itself passes through as bad input.
"""

from __future__ import annotations

import copy
import importlib
import importlib.metadata
import inspect
import re
import time
import warnings
from dataclasses import replace
from typing import Any, Callable, Iterable

import numpy as np

from elastoplast.certificate.kkt import certify, real_number
from elastoplast.certificate.solution import Solution, Status, make_solution
from elastoplast.errors import InputError, elide, short_repr
from elastoplast.fem.discretize import Discretization
from elastoplast.fem.material import return_mapping
from elastoplast.options import SolverOptions, check_array
from elastoplast.solvers.loop import within_tolerance

#: the entry-point group a distribution declares its methods in
GROUP = "elastoplast.methods"

#: ``package.module:object`` (dotted names both sides, as in an entry point's value)
SPEC = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")

#: the form of a method name that is imported rather than looked up
SPEC_FORM = "package.module:function"

#: (entry point, distribution) pairs already warned about in this process
_warned: set[tuple[str, str]] = set()


class PluginError(RuntimeError):
    """A method from outside failed in its run: it raised, or returned no answer.
    The message is one line naming the method; the original exception is the cause."""


def one_line(exc: BaseException) -> str:
    """``Type: message``, the message's first line, bounded."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {elide(text[0], 200)}" if text else type(exc).__name__


def exited(exc: BaseException) -> str:
    """:func:`one_line`, and for ``SystemExit`` the call that raised it (its code)."""
    if isinstance(exc, SystemExit):
        return f"SystemExit: sys.exit({elide(repr(exc.code), 60)}) was called"
    return one_line(exc)


def is_spec(name: str) -> bool:
    """Whether ``name`` is spelled as an import (``package.module:object``)."""
    return ":" in name


def import_object(spec: str, field: str) -> Any:
    """The object ``spec`` names, or an InputError naming ``field``: a spelling that
    is not ``package.module:object``, a module that does not import, a missing attribute."""
    if not SPEC.fullmatch(spec):
        raise InputError(field, f"{spec!r} is not {SPEC_FORM} (dotted Python names on both sides of one colon)")
    module_name, _, attrs = spec.partition(":")
    try:
        obj = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and (module_name == exc.name or module_name.startswith(exc.name + ".")):
            raise InputError(field, f"cannot import {module_name!r} for method {spec!r}: no module named {exc.name!r} "
                                    "(install it, or put its folder on PYTHONPATH)") from None
        raise InputError(field, f"importing {module_name!r} for method {spec!r} failed: {one_line(exc)}") from None
    except (Exception, SystemExit) as exc:  # a syntax error, sys.exit(), anything the module raises at import
        raise InputError(field, f"importing {module_name!r} for method {spec!r} failed: {exited(exc)}") from None
    for attr in attrs.split("."):
        if not hasattr(obj, attr):
            raise InputError(field, f"module {module_name!r} has no attribute {attrs!r} (method {spec!r})")
        obj = getattr(obj, attr)
    return obj


def distribution_of(entry: importlib.metadata.EntryPoint) -> str:
    """``name version`` of the distribution declaring ``entry`` (for messages)."""
    dist = getattr(entry, "dist", None)
    if dist is None:
        return "an unnamed distribution"
    return f"distribution {dist.metadata['Name'] or dist.name!s} {dist.version}"


def entry_points(builtins: Iterable[str] = ()) -> dict[str, list[importlib.metadata.EntryPoint]]:
    """The entry points of :data:`GROUP` by name, read from the installed
    distributions at each call (nothing cached). One named like a built-in
    method is left out, with a warning naming its distribution: built-ins win."""
    found: dict[str, list[importlib.metadata.EntryPoint]] = {}
    reserved = set(builtins)
    for entry in importlib.metadata.entry_points(group=GROUP):
        if entry.name in reserved:
            key = (entry.name, distribution_of(entry))
            if key not in _warned:
                _warned.add(key)
                warnings.warn(f"entry point {entry.name!r} ({entry.value}) of {key[1]} has the name of a built-in "
                              "method: the built-in wins, the entry point is never loaded")
            continue
        found.setdefault(entry.name, []).append(entry)
    return found


def find_entry_point(name: str, builtins: Iterable[str], field: str) -> importlib.metadata.EntryPoint | None:
    """The one entry point called ``name``, None if there is none; two of that
    name from different distributions are an InputError (which one is meant?)."""
    entries = entry_points(builtins).get(name, [])
    if len({(e.value, distribution_of(e)) for e in entries}) > 1:
        where = "; ".join(f"{e.value} in {distribution_of(e)}" for e in entries)
        raise InputError(field, f"method {name!r} is declared by {len(entries)} entry points ({where}): "
                                f"uninstall one, or give the object as {SPEC_FORM}")
    return entries[0] if entries else None


def load_entry_point(entry: importlib.metadata.EntryPoint, field: str) -> Any:
    """The object ``entry`` names, or an InputError naming its distribution."""
    try:
        return entry.load()
    except (Exception, SystemExit) as exc:
        raise InputError(field, f"entry point {entry.name!r} = {entry.value!r} of {distribution_of(entry)} failed "
                                f"to load: {exited(exc)}") from None


def check_function(fn: Any, where: str, field: str) -> None:
    """Refuse a callable that cannot be called as ``fn(disc, options)``."""
    try:
        signature = inspect.signature(fn)
    except (TypeError, ValueError):  # some builtins have none: let the call decide
        return
    try:
        signature.bind(None, None)
    except TypeError:
        raise InputError(field, f"{where} cannot be called as run(disc, options): its signature is "
                                f"{elide(str(signature), 120)}") from None


def judged(run: Callable[[Discretization, SolverOptions], Any], name: str
           ) -> Callable[[Discretization, SolverOptions], Solution]:
    """``run`` with its answer certified and judged (:func:`judge`); an exception
    other than an InputError becomes a :class:`PluginError` naming ``name``."""

    def judged_run(disc: Discretization, options: SolverOptions) -> Solution:
        start = time.perf_counter()
        try:  # its own copy (read-only arrays, its own attributes): judged against the problem as given
            out = run(copy.copy(disc), options)
        except (InputError, MemoryError):
            raise
        except (Exception, SystemExit) as exc:  # sys.exit() in a plug-in ends nothing but the plug-in
            raise PluginError(f"method {name!r} raised {exited(exc)}") from exc
        return judge(disc, out, name, options.tol, time.perf_counter() - start)

    judged_run.__doc__ = run.__doc__
    return judged_run


def guarded(check: Callable[[Discretization, SolverOptions], None] | None, name: str
            ) -> Callable[[Discretization, SolverOptions], None] | None:
    """A method's ``check(disc, options)`` with any exception but an InputError made a
    :class:`PluginError` naming ``name`` (None stays None)."""
    if check is None:
        return None

    def guarded_check(disc: Discretization, options: SolverOptions) -> None:
        try:
            check(copy.copy(disc), options)
        except (InputError, MemoryError):
            raise
        except (Exception, SystemExit) as exc:
            raise PluginError(f"method {name!r}: its check raised {exited(exc)}") from exc

    return guarded_check


def nodal(u: Any, disc: Discretization) -> np.ndarray:
    """A method's ``u`` as given: numbers of shape ``(n_nodes, d)``, never reshaped (a
    transposed or flattened ``u`` is a bug of the method, which a reshape would hide)."""
    shape = (disc.mesh.n_nodes, disc.dim)
    arr = check_array("u", u)
    if arr.shape != shape:
        raise InputError("u", f"expected shape {shape} (n_nodes, d), got {arr.shape}")
    return arr


def judge(disc: Discretization, out: Any, name: str, tol: float, elapsed: float) -> Solution:
    """The :class:`Solution` of a method's answer ``out``, certified here.

    ``out`` is a Solution (its arrays, message, iterations, timings and history are
    kept, its status and certificate are not), ``(u, U)`` or ``(u, U, sigma, xi)``
    with ``u`` nodal ``(n_nodes, d)``; stresses absent are the return mapping of
    ``u``. The status is CONVERGED exactly when the certificate passes ``tol``,
    with ``u``'s fixed components judged as given (``dirichlet``); otherwise the
    method's own status if it gave one that is not CONVERGED, else FAILED, the
    message saying why. :func:`make_solution` applies its own checks on top (NaN,
    small strains). An answer that is none of these is a :class:`PluginError`."""
    claimed, message, iterations, timings, history, lam = None, "", 0, {"total": elapsed}, [], None
    try:
        if isinstance(out, Solution):
            claimed, message, iterations, history = out.status, out.message, out.iterations, out.history
            timings = dict(out.timings) or timings
            u, U, sigma, xi, lam = out.u, out.U, out.sigma, out.xi, out.contact_force
        elif isinstance(out, tuple) and len(out) in (2, 4):
            u, U = out[0], out[1]
            u = nodal(u, disc)
            if len(out) == 4:
                sigma, xi = out[2], out[3]
            else:
                sigma, xi, _ = return_mapping(disc.material, disc.strain(disc.free_displacement(u)), disc.state)
        else:
            raise PluginError(f"method {name!r} returned {short_repr(out)}: expected a Solution, (u, U) or "
                              "(u, U, sigma, xi)")
        u = nodal(u, disc)
        U = real_number("U", U)
        sol = make_solution(disc, method=name, status=Status.CONVERGED, sigma=sigma, xi=xi,
                            u_free=disc.free_displacement(u), U=U, contact_force=lam, iterations=iterations,
                            timings=timings, message=message, history=history)
    except InputError as exc:  # a shape or type of the method's own making: its bug, not the user's input
        raise PluginError(f"method {name!r} returned a bad answer: {exc}") from None
    if sol.status is not Status.CONVERGED:  # make_solution's own verdict (NaN, small strains) stands
        return replace(sol, status=claimed if claimed not in (None, Status.CONVERGED) else sol.status)
    reasons = []
    if not within_tolerance(sol.kkt, tol):
        reasons.append(f"the certificate's worst residual {sol.kkt.worst:.2e} is above tol {tol:g}")
    dirichlet = certify(disc, sol.sigma, sol.xi, u, U, contact_force=sol.contact_force).dirichlet \
        if np.any(u.reshape(-1)[disc.fixed]) else 0.0
    if not dirichlet <= tol:
        reasons.append(f"its u moves fixed components (dirichlet residual {dirichlet:.2e}, "
                       "the Solution holds them at zero)")
    if not reasons:
        return sol
    status = claimed if claimed not in (None, Status.CONVERGED) else Status.FAILED
    said = f"{message}; " if message else ""
    return replace(sol, status=status, message=said + "; ".join(reasons))
