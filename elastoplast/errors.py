"""The one exception users see for bad input."""

from __future__ import annotations


class InputError(ValueError):
    """Bad problem input. ``field`` names the offending key, e.g. ``material.nu``."""

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message


def expect(value, kind: type, field: str, hint: str = "") -> None:
    """Refuse ``value`` unless it is a ``kind``: the entry points of the Python API
    name the argument instead of failing deep inside (``hint``: how to make one)."""
    if not isinstance(value, kind):
        raise InputError(field, f"expected a {kind.__name__}{f' ({hint})' if hint else ''}, got {type(value).__name__}")
