"""Solver options: declared once, checked in one place, whatever the entry point.

Every method's options are a frozen dataclass deriving from
:class:`SolverOptions`; each field is declared with :func:`option`, which
records its type, its admissible range and a one-line description. The
checks run in ``__post_init__``, so a command-line flag, a ``[solver]`` table,
a campaign axis, ``ep.solve(disc, method, **options)`` and a dataclass built by
hand all go through the same code and fail with the same
:class:`~elastoplast.errors.InputError` naming the option.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from elastoplast.errors import InputError
from elastoplast.errors import short_repr

#: the loosest certificate tolerance that still means "solved": every residual of the
#: certificate is relative, so 1e-2 already admits a 1% error in force balance
LOOSEST_TOL = 1e-2
#: the tightest: the certificate of an exact answer is itself computed with round-off
#: (measured 1e-16 .. 3e-13 on the problems of benchmarks/uzawa, growing with the mesh)
TIGHTEST_TOL = 1e-13
#: hard ceiling of any iteration count (a loop at 1 ms per iteration runs 17 minutes)
MAX_ITER_CEILING = 1_000_000


@dataclass(frozen=True)
class Spec:
    """What a field admits: ``kind`` (float, int, bool, str, object for anything, or
    a class whose instances only are admitted), a closed
    range ``[lo, hi]`` (``lo_open``: ``lo`` excluded), ``choices`` for strings,
    ``none`` when ``None`` is allowed, ``persist`` False for run-time settings
    that do not change the answer (progress bars, warm starts) and so stay out
    of stored inputs and hashes."""

    kind: type
    doc: str
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[str, ...] | None = None
    none: bool = False
    persist: bool = True


def option(default: Any, kind: type, doc: str, **spec: Any) -> Any:
    """A dataclass field carrying its :class:`Spec`."""
    return dataclasses.field(default=default, metadata={"spec": Spec(kind, doc, **spec)})


def _describe(spec: Spec) -> str:
    if spec.choices is not None:
        return f"one of {list(spec.choices)}"
    if spec.kind is bool:
        return "true or false"
    what = {int: "an integer", float: "a number", str: "a string", object: "a value"}.get(spec.kind)
    if what is None:  # an object only Python can pass (a warm start): no file or flag holds one
        return f"a {spec.kind.__name__} object, given from Python" + (" (or none)" if spec.none else "")
    if spec.lo is not None and spec.hi is not None:
        what += f" in {'(' if spec.lo_open else '['}{spec.lo:g}, {spec.hi:g}]"
    elif spec.lo is not None:
        what += f" {'>' if spec.lo_open else '>='} {spec.lo:g}"
    elif spec.hi is not None:
        what += f" <= {spec.hi:g}"
    return what + (" (or none)" if spec.none else "")



def check_value(name: str, value: Any, spec: Spec) -> Any:
    """``value`` converted to the field's kind, or an InputError naming ``name``."""
    if value is None and spec.none:
        return None
    if spec.kind is object:
        return value
    bad = InputError(name, f"must be {_describe(spec)}, got {short_repr(value)}")
    if spec.kind not in (bool, str, int, float):
        if not isinstance(value, spec.kind):
            raise bad
        return value
    if spec.kind is bool:
        if not isinstance(value, bool):
            raise bad
        return value
    if spec.kind is str:
        if not isinstance(value, str) or (spec.choices is not None and value not in spec.choices):
            raise bad
        return value
    if isinstance(value, bool):
        raise bad
    if spec.kind is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, numbers.Integral):  # numpy integers too
            raise bad
        value = int(value)
    elif spec.kind is float:
        if not isinstance(value, numbers.Real):
            raise bad
        try:
            value = float(value)
        except OverflowError:  # an integer beyond any float
            raise bad from None
        if not math.isfinite(value):
            raise bad
    if spec.lo is not None and (value < spec.lo or (spec.lo_open and value == spec.lo)):
        raise bad
    if spec.hi is not None and value > spec.hi:
        raise bad
    return value


def check_array(name: str, value: Any) -> np.ndarray:
    """``value`` as a float array of any shape, or an InputError naming ``name``:
    numbers only, never strings, booleans, ``None`` or objects, which numpy would
    convert or keep as objects (``np.asarray(['1'], float)`` is ``[1.0]``). NaN and
    infinity pass: the caller says what it needs of the values and of the shape."""
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):  # ragged nested lists
        arr = np.asarray(None)
    if arr.dtype.kind not in "iuf":
        raise InputError(name, f"expected an array of numbers, got {short_repr(value)}")
    return arr.astype(float, copy=False)


@dataclass(frozen=True)
class SolverOptions:
    """Options every method has.

    ``tol``: the answer is CONVERGED only when every relative residual of the
    KKT certificate (docs/certificate.md) is at most ``tol``; ``max_iter`` and
    ``time_limit`` bound the run; ``progress`` reports on stderr.
    """

    tol: float = option(1e-6, float, "bound on every relative KKT residual of the answer",
                        lo=TIGHTEST_TOL, hi=LOOSEST_TOL)
    max_iter: int = option(1000, int, "iteration limit", lo=1, hi=MAX_ITER_CEILING)
    time_limit: float | None = option(None, float, "wall-clock limit in seconds", lo=0.0, lo_open=True, none=True,
                                      persist=False)
    progress: bool = option(False, bool, "report progress on stderr", persist=False)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            spec = f.metadata.get("spec")
            if spec is not None:
                object.__setattr__(self, f.name, check_value(f.name, getattr(self, f.name), spec))

    @classmethod
    def specs(cls) -> dict[str, Spec]:
        """Every option of this class with its :class:`Spec`, in declaration order."""
        return {f.name: f.metadata["spec"] for f in dataclasses.fields(cls) if "spec" in f.metadata}

    @classmethod
    def build(cls, values: Mapping[str, Any] | None = None, *, method: str = "", prefix: str = "") -> "SolverOptions":
        """Options from a mapping; unknown names are refused, errors name
        ``prefix + option`` (``"solver."`` for a TOML table, ``"--"`` for flags).
        Anything but a mapping (or ``None``, the defaults) is refused naming the
        table (``prefix`` without its dot) or ``options``."""
        if values is not None and not isinstance(values, Mapping):
            field = prefix[:-1] if prefix.endswith(".") else "options"
            raise InputError(field, f"expected a mapping of option names to values (or a {cls.__name__}), "
                                    f"got {short_repr(values)}")
        values = dict(values or {})
        specs = cls.specs()
        for name in values:
            if name not in specs:
                whose = f"method {method!r}" if method else cls.__name__
                raise InputError(f"{prefix}{name}", f"{whose} has no option {name!r} (its options: {', '.join(specs)})")
        try:
            return cls(**values)
        except InputError as exc:
            raise InputError(f"{prefix}{exc.field}", exc.message) from None

    @classmethod
    def of(cls, value: "SolverOptions | Mapping[str, Any] | None", field: str = "options") -> "SolverOptions":
        """``value`` as options of this class: ``None`` (the defaults), an instance, or a
        mapping of option names (:meth:`build`); anything else is refused naming ``field``."""
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, Mapping):
            return cls.build(value, prefix=f"{field}.")
        raise InputError(field, f"expected {cls.__name__} or a mapping of its options, got {type(value).__name__}")

    def persistent(self) -> dict[str, Any]:
        """The options that can change the answer, as plain values (for stored inputs and hashes)."""
        return {name: getattr(self, name) for name, spec in self.specs().items() if spec.persist}
