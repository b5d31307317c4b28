"""The method registry: one name per solver, all returning a certified Solution.

A method is ``fn(disc, **options) -> Solution``; adding one is one line in
:data:`METHODS`.
"""

from __future__ import annotations

from typing import Any, Callable

from .accelerated import uzawa_fast_method
from .conic import ConicOptions, solve_conic, solve_conic_cvxpy, solve_conic_displacement
from .discretize import Discretization
from .errors import InputError
from .newton import newton_method
from .solution import Solution
from .uzawa import uzawa_method


def _conic(fn):
    def run(disc: Discretization, tol: float | None = None, max_iter: int | None = None, **_: Any) -> Solution:
        opts = ConicOptions()
        kw = {k: v for k, v in (("tol", tol), ("max_iter", max_iter)) if v is not None}
        return fn(disc, ConicOptions(**{**opts.__dict__, **kw}))

    run.__doc__ = fn.__doc__
    return run


METHODS: dict[str, Callable[..., Solution]] = {
    "conic": _conic(solve_conic),
    "conic-cvxpy": _conic(solve_conic_cvxpy),
    "conic-displacement": _conic(solve_conic_displacement),
    "uzawa": uzawa_method,
    "newton": newton_method,
    "uzawa-fast": uzawa_fast_method,
}


def solve(disc: Discretization, method: str = "conic", **options: Any) -> Solution:
    """Solve (2.1) by ``method`` (a key of :data:`METHODS`)."""
    if method not in METHODS:
        raise InputError("method", f"unknown method {method!r} (choose from {sorted(METHODS)})")
    return METHODS[method](disc, **options)
