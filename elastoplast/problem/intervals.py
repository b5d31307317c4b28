"""Rigorous interval enclosures of a user-given obstacle expression (docs/bounds.md).

The lower bound needs ``int_f lam psi`` over-estimated on every contact facet. For
``shape = "expression"`` nothing is known about convexity, so psi is enclosed by
interval arithmetic on the expression's syntax tree (the same restricted grammar
as :func:`elastoplast.problem.expressions.compile_expression`), over boxes covering pieces of
each facet. Every operation rounds outward: ``+ - * /`` and ``sqrt`` (correctly
rounded in IEEE arithmetic) by one ulp, library functions (exp, log, sin, ...,
within a few ulps of the exact value in glibc) by ``LIBM_ULPS`` relative units of
round-off. Literals and ``pi``, ``e`` are the doubles the point evaluation uses:
the obstacle *is* the formula as numpy evaluates it on exact arguments.

Anything the enclosure cannot bound (an unsupported operator, a division by an
interval containing 0, a domain error, an unbounded result) is reported with its
reason, and the caller then reports its bound as not certified.
"""

from __future__ import annotations

import ast

import numpy as np

from elastoplast.problem.expressions import compile_expression

#: relative widening of library-function results, in units of machine epsilon
LIBM_ULPS = 4.0
_EPS = np.finfo(float).eps
_TINY = np.finfo(float).tiny


class Unbounded(Exception):
    """The enclosure cannot bound the expression; the message says why."""


def _down(a, ulps: float = 0.0):
    """One ulp below ``a`` (enough after a correctly rounded operation), and ``ulps``
    relative units of round-off further for library functions."""
    a = np.nextafter(a, -np.inf)
    return a - ulps * _EPS * np.abs(a) - _TINY if ulps else a


def _up(a, ulps: float = 0.0):
    a = np.nextafter(a, np.inf)
    return a + ulps * _EPS * np.abs(a) + _TINY if ulps else a


class Truth:
    """Three-valued comparison result: where it may be true, where it may be false."""

    def __init__(self, maybe_true, maybe_false):
        self.maybe_true = np.asarray(maybe_true, dtype=bool)
        self.maybe_false = np.asarray(maybe_false, dtype=bool)


def _truth(v) -> Truth:
    if isinstance(v, Truth):
        return v
    lo, hi = v
    return Truth(~((lo == 0) & (hi == 0)), (lo <= 0) & (hi >= 0))


def _select(cond, a, b):
    """``where(cond, a, b)``: a where surely true, b where surely false, the hull otherwise."""
    t = _truth(cond)
    lo = np.where(t.maybe_true & t.maybe_false, np.minimum(a[0], b[0]), np.where(t.maybe_true, a[0], b[0]))
    hi = np.where(t.maybe_true & t.maybe_false, np.maximum(a[1], b[1]), np.where(t.maybe_true, a[1], b[1]))
    return lo, hi


def _mul(a, b):
    c = np.stack([a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1]])
    if np.isnan(c).any():
        raise Unbounded("0 times an unbounded interval")
    return _down(c.min(axis=0)), _up(c.max(axis=0))


def _div(a, b):
    if np.any((b[0] <= 0) & (b[1] >= 0)):
        raise Unbounded("division by an interval that contains 0")
    c = np.stack([a[0] / b[0], a[0] / b[1], a[1] / b[0], a[1] / b[1]])
    return _down(c.min(axis=0)), _up(c.max(axis=0))


def _monotone(f, a, increasing=True):
    lo, hi = f(a[0]), f(a[1])
    if not increasing:
        lo, hi = hi, lo
    return _down(lo, LIBM_ULPS), _up(hi, LIBM_ULPS)


def _ipow(a, n: int):
    if n == 0:
        return np.ones_like(a[0]), np.ones_like(a[0])
    if n < 0:
        return _div((np.ones_like(a[0]), np.ones_like(a[0])), _ipow(a, -n))
    lo, hi = a
    if n % 2 == 0:
        mag_lo = np.where((lo <= 0) & (hi >= 0), 0.0, np.minimum(np.abs(lo), np.abs(hi)))
        mag_hi = np.maximum(np.abs(lo), np.abs(hi))
        return _monotone(lambda t: np.power(t, n), (mag_lo, mag_hi))
    return _monotone(lambda t: np.power(t, n), a)


def _pow(a, b):
    if np.all(b[0] == b[1]) and np.all(b[0] == np.round(b[0])) and np.all(b[0] == b[0].flat[0]):
        return _ipow(a, int(b[0].flat[0]))
    if np.any(a[0] < 0) or np.any((a[0] == 0) & (b[0] <= 0)):
        raise Unbounded("a non-integer power of an interval reaching below 0")
    c = np.stack([np.power(a[i], b[j]) for i in (0, 1) for j in (0, 1)])
    return _down(c.min(axis=0), LIBM_ULPS), _up(c.max(axis=0), LIBM_ULPS)


def _periodic(a, f, peak: float, trough: float):
    """sin or cos (period 2 pi): endpoint values, and +-1 where a peak/trough may lie inside."""
    lo, hi = a
    if np.any(~np.isfinite(lo) | ~np.isfinite(hi)):
        raise Unbounded("sin/cos of an unbounded interval")
    pad = 1e-12 * (1.0 + np.maximum(np.abs(lo), np.abs(hi)))

    def contains(x0):
        return np.ceil((lo - pad - x0) / (2 * np.pi)) <= np.floor((hi + pad - x0) / (2 * np.pi))

    v = np.stack([f(lo), f(hi)])
    out_lo = np.where(contains(trough), -1.0, _down(v.min(axis=0), LIBM_ULPS))
    out_hi = np.where(contains(peak), 1.0, _up(v.max(axis=0), LIBM_ULPS))
    return np.maximum(out_lo, -1.0), np.minimum(out_hi, 1.0)


def _tan(a):
    lo, hi = a
    pad = 1e-12 * (1.0 + np.maximum(np.abs(lo), np.abs(hi)))
    if np.any(np.ceil((lo - pad - np.pi / 2) / np.pi) <= np.floor((hi + pad - np.pi / 2) / np.pi)):
        raise Unbounded("tan across a pole")
    return _monotone(np.tan, a)


def _sqrt(a):
    if np.any(a[1] < 0):
        raise Unbounded("sqrt of a negative interval")
    return np.maximum(_down(np.sqrt(np.maximum(a[0], 0.0))), 0.0), _up(np.sqrt(a[1]))


def _log(a):
    if np.any(a[1] <= 0):
        raise Unbounded("log of a non-positive interval")
    return _down(np.log(np.maximum(a[0], 0.0)), LIBM_ULPS), _up(np.log(a[1]), LIBM_ULPS)


def _domain(f, lo_lim, hi_lim, increasing=True):
    def g(a):
        if np.any((a[1] < lo_lim) | (a[0] > hi_lim)):
            raise Unbounded(f"{f.__name__} outside its domain")
        clipped = (np.maximum(a[0], lo_lim), np.minimum(a[1], hi_lim))
        return _monotone(f, clipped, increasing)

    return g


def _nonnegative(a):
    return np.maximum(a[0], 0.0), a[1]


def _abs(a):
    lo, hi = a
    return (np.where((lo <= 0) & (hi >= 0), 0.0, np.minimum(np.abs(lo), np.abs(hi))), np.maximum(np.abs(lo), np.abs(hi)))


def _cosh(a):
    lo, hi = _monotone(np.cosh, _abs(a))
    return np.maximum(lo, 1.0), hi


def _hypot(a, b):
    x, y = _abs(a), _abs(b)
    return np.maximum(_down(np.hypot(x[0], y[0]), LIBM_ULPS), 0.0), _up(np.hypot(x[1], y[1]), LIBM_ULPS)


_FUNCTIONS = {
    "sqrt": _sqrt,
    "exp": lambda a: _nonnegative(_monotone(np.exp, a)),
    "log": _log,
    "sin": lambda a: _periodic(a, np.sin, np.pi / 2, -np.pi / 2),
    "cos": lambda a: _periodic(a, np.cos, 0.0, np.pi),
    "tan": _tan,
    "arctan": lambda a: _monotone(np.arctan, a),
    "arcsin": _domain(np.arcsin, -1.0, 1.0),
    "arccos": _domain(np.arccos, -1.0, 1.0, increasing=False),
    "sinh": lambda a: _monotone(np.sinh, a),
    "cosh": _cosh,
    "tanh": lambda a: _monotone(np.tanh, a),
    "abs": _abs,
    "minimum": lambda a, b: (np.minimum(a[0], b[0]), np.minimum(a[1], b[1])),
    "maximum": lambda a, b: (np.maximum(a[0], b[0]), np.maximum(a[1], b[1])),
    "hypot": _hypot,
    "where": _select,
}
_CONSTANTS = {"pi": np.pi, "e": np.e}


def _compare(op, a, b) -> Truth:
    (alo, ahi), (blo, bhi) = a, b
    if isinstance(op, ast.Lt):
        return Truth(alo < bhi, ahi >= blo)
    if isinstance(op, ast.LtE):
        return Truth(alo <= bhi, ahi > blo)
    if isinstance(op, ast.Gt):
        return Truth(ahi > blo, alo <= bhi)
    if isinstance(op, ast.GtE):
        return Truth(ahi >= blo, alo < bhi)
    overlap = (alo <= bhi) & (blo <= ahi)
    point_equal = (alo == ahi) & (blo == bhi) & (alo == blo)
    if isinstance(op, ast.Eq):
        return Truth(overlap, ~point_equal)
    if isinstance(op, ast.NotEq):
        return Truth(~point_equal, overlap)
    raise Unbounded(f"comparison {type(op).__name__} is not supported")


def _eval(node, env):
    if isinstance(node, ast.Expression):
        return _eval(node.body, env)
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise Unbounded(f"constant {node.value!r} is not a number")
        v = np.full(env["x"][0].shape, float(node.value))
        return v, v
    if isinstance(node, ast.Name):
        if node.id in env:
            return env[node.id]
        if node.id in _CONSTANTS:
            v = np.full(env["x"][0].shape, _CONSTANTS[node.id])
            return v, v
        raise Unbounded(f"name {node.id!r} is not a value")
    if isinstance(node, ast.UnaryOp):
        a = _eval(node.operand, env)
        if isinstance(node.op, ast.USub):
            return -a[1], -a[0]
        if isinstance(node.op, ast.UAdd):
            return a
        raise Unbounded(f"operator {type(node.op).__name__} is not supported")
    if isinstance(node, ast.BinOp):
        a, b = _eval(node.left, env), _eval(node.right, env)
        if isinstance(node.op, ast.Add):
            return _down(a[0] + b[0]), _up(a[1] + b[1])
        if isinstance(node.op, ast.Sub):
            return _down(a[0] - b[1]), _up(a[1] - b[0])
        if isinstance(node.op, ast.Mult):
            return _mul(a, b)
        if isinstance(node.op, ast.Div):
            return _div(a, b)
        if isinstance(node.op, ast.Pow):
            return _pow(a, b)
        raise Unbounded(f"operator {type(node.op).__name__} is not supported")
    if isinstance(node, ast.Call):
        name = node.func.id if isinstance(node.func, ast.Name) else None
        if name not in _FUNCTIONS or node.keywords:
            raise Unbounded(f"function {name!r} is not supported")
        args = [_eval(arg, env) for arg in node.args]
        return _FUNCTIONS[name](*args)
    if isinstance(node, ast.Compare):
        left = _eval(node.left, env)
        result = None
        for op, comp in zip(node.ops, node.comparators):
            right = _eval(comp, env)
            t = _compare(op, left, right)
            result = t if result is None else Truth(result.maybe_true & t.maybe_true, result.maybe_false | t.maybe_false)
            left = right
        return result
    if isinstance(node, ast.IfExp):
        return _select(_eval(node.test, env), _eval(node.body, env), _eval(node.orelse, env))
    raise Unbounded(f"{type(node).__name__} is not supported")


def enclose(expression: str, dim: int, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` bounds of the expression over the boxes ``[lo, hi]`` (m, d-1).

    Raises :class:`Unbounded` with the reason when no finite enclosure is found.
    """
    code = compile_expression(expression, dim, "obstacle.expression")  # validates the grammar
    del code
    tree = ast.parse(expression, mode="eval")
    env = {"x": (lo[:, 0], hi[:, 0])}
    if dim == 3:
        env["y"] = (lo[:, 1], hi[:, 1])
    out = _eval(tree, env)
    if isinstance(out, Truth):
        raise Unbounded("the expression is a comparison, not a number")
    low, up = (np.broadcast_to(np.asarray(v, dtype=float), lo[:, 0].shape) for v in out)
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(up))):
        raise Unbounded("the enclosure is not finite")
    return low, up


def facet_pieces(dim: int, m: int) -> np.ndarray:
    """Barycentric vertices ``(P, dim, dim)`` of the regular subdivision of a facet
    (a segment in 2D: m pieces; a triangle in 3D: m^2 pieces), all of equal measure."""
    if dim == 2:
        t = np.arange(m + 1) / m
        ends = np.stack([t[:-1], t[1:]], axis=1)  # (m, 2) parameter of each piece's ends
        return np.stack([1 - ends, ends], axis=2)
    pts = []
    for i in range(m):
        for j in range(m - i):
            pts.append([(i, j), (i + 1, j), (i, j + 1)])
            if i + j <= m - 2:
                pts.append([(i + 1, j), (i, j + 1), (i + 1, j + 1)])
    ij = np.asarray(pts, dtype=float) / m  # (P, 3, 2): weights of vertices 1 and 2
    return np.concatenate([1 - ij.sum(axis=2, keepdims=True), ij], axis=2)


def enclose_on_simplices(obstacle, X: np.ndarray, measure: np.ndarray, m: int) -> tuple[np.ndarray | None, str]:
    """Weights ``q (n_f, d)`` with ``q_fa >= int_f psi b_a`` on facets with in-plane vertex
    coordinates ``X (n_f, d, d-1)`` and measures ``measure``.

    Each facet is cut into ``P`` pieces of equal measure (:func:`facet_pieces`); psi is
    enclosed on the bounding box of each piece (widened by 1e-12 of the facet size
    against the rounding of the piece corners) and
    ``q_fa = sum_p max_p psi * (|f| / P) * mean of b_a over the piece's vertices``
    (exact for the linear b_a), rounded up. Returns ``(None, reason)`` when psi cannot
    be enclosed.
    """
    dim = X.shape[1]
    bary = facet_pieces(dim, m)  # (P, d, d)
    corners = np.einsum("pva,fac->fpvc", bary, X)  # (n_f, P, d vertices, d-1)
    size = np.abs(X.max(axis=1) - X.min(axis=1)).max(axis=1)
    pad = (1e-12 * size + _TINY)[:, None, None]
    lo = corners.min(axis=2) - pad
    hi = corners.max(axis=2) + pad
    try:
        _, upper = enclose(obstacle.expression, obstacle.dim, lo.reshape(-1, dim - 1), hi.reshape(-1, dim - 1))
    except Unbounded as exc:
        return None, str(exc)
    upper = upper.reshape(lo.shape[:2])  # (n_f, P)
    share = bary.mean(axis=1)  # (P, d): mean of b_a over each piece
    q = measure[:, None] / bary.shape[0] * np.einsum("fp,pa->fa", upper, share)
    return q + 1e-14 * np.abs(q), ""
