"""The one exception users see for bad input, and the few helpers that word it."""

from __future__ import annotations

import math
import numbers
from typing import Any

import numpy as np

#: the longest field name and message an :class:`InputError` carries (longer ones are cut in the middle)
FIELD_WIDTH = 100
MESSAGE_WIDTH = 500


def elide(text: str, width: int) -> str:
    """``text`` cut in the middle to at most ``width`` characters, its start and its end kept:
    a 100,000-character name (a TOML key, a flag, a path) stays recognisable in a one-line message."""
    text = str(text)
    if len(text) <= width:
        return text
    head = (width - 3) * 11 // 20
    return f"{text[:head]}...{text[len(text) - (width - 3 - head):]}"


class InputError(ValueError):
    """Bad problem input. ``field`` names the offending key, e.g. ``material.nu``.

    Both are cut in the middle (:func:`elide`) to :data:`FIELD_WIDTH` and
    :data:`MESSAGE_WIDTH` characters, so that whatever the user wrote, the
    message stays one readable line."""

    def __init__(self, field: str, message: str):
        field, message = elide(field, FIELD_WIDTH), elide(message, MESSAGE_WIDTH)
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


def expect(value, kind: type, field: str, hint: str = "") -> None:
    """Refuse ``value`` unless it is a ``kind``: the entry points of the Python API
    name the argument instead of failing deep inside (``hint``: how to make one)."""
    if not isinstance(value, kind):
        raise InputError(field, f"expected a {kind.__name__}{f' ({hint})' if hint else ''}, got {type(value).__name__}")


def finite_float(val: Any) -> float | None:
    """``val`` as a finite float (``-0.0`` made ``0.0``), or None for anything else:
    booleans, strings, tables, lists, ``None``, ``nan``, ``inf`` and integers beyond the float range."""
    if isinstance(val, (bool, np.bool_)) or not isinstance(val, numbers.Real):
        return None
    try:
        f = float(val)
    except (OverflowError, ValueError, TypeError):
        return None
    return f + 0.0 if math.isfinite(f) else None


def short_repr(val: Any, width: int = 80) -> str:
    """``repr`` of a user value, cut to one readable line of about ``width`` characters;
    an array is described by its shape and type (numpy's printout spans lines)."""
    if isinstance(val, np.ndarray):
        return f"an array of shape {val.shape} and dtype {val.dtype}"
    text = " ".join(repr(val).split())
    return text if len(text) <= width else text[: max(width - 20, 10)] + f"... ({len(text)} characters)"


def figure(value: Any, spec: str) -> str:
    """A printed figure; ``n/a`` for one that is not a finite number (a diverged run's NaN)."""
    try:
        return format(value, spec) if math.isfinite(value) else "n/a"
    except (TypeError, ValueError):
        return "n/a"
