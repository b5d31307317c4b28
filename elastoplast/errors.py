"""The one exception users see for bad input."""

from __future__ import annotations


class InputError(ValueError):
    """Bad problem input. ``field`` names the offending key, e.g. ``material.nu``."""

    def __init__(self, field: str, message: str):
        super().__init__(f"{field}: {message}")
        self.field = field
        self.message = message
