"""Obstacle formulas: a restricted grammar of arithmetic and numpy maths in x (and y), compiled at a bounded cost.

A user's ``shape = "expression"`` obstacle is Python syntax, parsed and checked node by node
before anything is evaluated (:func:`compile_expression`); the same grammar is enclosed by
interval arithmetic in :mod:`elastoplast.problem.intervals`.
"""

from __future__ import annotations

import ast

import numpy as np

from elastoplast.errors import InputError

SAFE_FUNCTIONS = {
    name: getattr(np, name)
    for name in ("sqrt", "exp", "log", "sin", "cos", "tan", "arctan", "arcsin", "arccos",
                 "sinh", "cosh", "tanh", "abs", "minimum", "maximum", "where", "pi", "hypot")
}
SAFE_FUNCTIONS["e"] = np.e
_ARITY = {name: 1 for name in SAFE_FUNCTIONS if callable(SAFE_FUNCTIONS[name])}
_ARITY.update(minimum=2, maximum=2, hypot=2, where=3)
_OPERATORS = (ast.Add, ast.Sub, ast.Mult, ast.Div, ast.Pow, ast.Mod, ast.FloorDiv, ast.UAdd, ast.USub,
              ast.Lt, ast.LtE, ast.Gt, ast.GtE, ast.Eq, ast.NotEq)
MAX_EXPRESSION_CHARS = 2000
MAX_EXPRESSION_NODES = 500


class _FloatConstants(ast.NodeTransformer):
    """Replace every number by a name bound to a NumPy float64.

    Python integers are exact and unbounded: ``9**9**9**9`` or ``10**10**8`` would run
    for minutes and take gigabytes before any check. NumPy floats overflow to ``inf``
    at once (refused afterwards as not finite), so every evaluation costs a few
    operations per node and node of the expression.
    """

    def __init__(self) -> None:
        self.values: dict[str, np.float64] = {}

    def visit_Constant(self, node: ast.Constant) -> ast.AST:
        try:
            value = np.float64(float(node.value))
        except OverflowError:  # an integer literal beyond the float range
            value = np.float64(np.inf)
        name = f"_c{len(self.values)}"
        self.values[name] = value
        return ast.copy_location(ast.Name(id=name, ctx=ast.Load()), node)


def compile_expression(expr: str, dim: int, fieldname: str, axisymmetric: bool = False):
    """Compile a formula in x (and y in 3D; r, the same as x, in an axisymmetric model)
    allowing only arithmetic and numpy maths.

    Returns ``(code, constants)``: evaluate with ``eval(code, {"__builtins__": {}},
    {**SAFE_FUNCTIONS, **constants, "x": ..., "y": ...})``. The cost is bounded: at most
    ``MAX_EXPRESSION_CHARS`` characters and ``MAX_EXPRESSION_NODES`` syntax nodes; only
    numbers (made float64), the variables, ``+ - * / // % **``, comparisons, ``a if c
    else b`` and calls of the functions of ``SAFE_FUNCTIONS`` with their own number of
    arguments (no keywords): every intermediate value is a float or an array shaped
    like ``x``.
    """
    variables = {"x", "y"} if dim == 3 else {"x", "r"} if axisymmetric else {"x"}
    if len(expr) > MAX_EXPRESSION_CHARS:
        raise InputError(fieldname, f"the formula has {len(expr)} characters (at most {MAX_EXPRESSION_CHARS})")
    try:
        tree = ast.parse(expr.strip(), mode="eval")
    except SyntaxError as exc:
        raise InputError(fieldname, f"cannot parse {expr!r}: {exc.msg}") from None
    except (ValueError, RecursionError, MemoryError) as exc:  # NUL bytes; nesting too deep
        raise InputError(fieldname, f"cannot parse {expr!r}: {type(exc).__name__}") from None
    allowed = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Call, ast.Name, ast.Load, ast.Constant,
               ast.Compare, ast.IfExp) + _OPERATORS
    nodes = list(ast.walk(tree))
    if len(nodes) > MAX_EXPRESSION_NODES:
        raise InputError(fieldname, f"the formula has {len(nodes)} syntax nodes (at most {MAX_EXPRESSION_NODES})")
    for node in nodes:
        if not isinstance(node, allowed):
            raise InputError(fieldname, f"{type(node).__name__} is not allowed in {expr!r}")
        if isinstance(node, ast.Name) and node.id not in variables and node.id not in SAFE_FUNCTIONS:
            raise InputError(fieldname, f"unknown name {node.id!r} in {expr!r} (variables: {sorted(variables)})")
        if isinstance(node, ast.Constant) and (isinstance(node.value, bool) or not isinstance(node.value, (int, float))):
            raise InputError(fieldname, f"only real numbers may appear as constants in {expr!r}, got {node.value!r}")
        if isinstance(node, ast.Call):
            name = node.func.id if isinstance(node.func, ast.Name) else None
            if name not in _ARITY or node.keywords or len(node.args) != _ARITY[name]:
                raise InputError(fieldname, f"calls must be one of {sorted(_ARITY)} with their own number of "
                                            f"arguments (where: 3; minimum, maximum, hypot: 2; others: 1) in {expr!r}")
    constants = _FloatConstants()
    tree = ast.fix_missing_locations(constants.visit(tree))
    try:
        return compile(tree, "<obstacle expression>", "eval"), constants.values
    except (ValueError, RecursionError, MemoryError) as exc:
        raise InputError(fieldname, f"cannot compile {expr!r}: {type(exc).__name__}") from None
