"""The package's version, declared once in pyproject.toml and read from the installed metadata."""

from __future__ import annotations

import importlib.metadata as _metadata

try:  # every install (pip install -e . included) records it
    __version__ = _metadata.version("elastoplast")
except _metadata.PackageNotFoundError:  # a source tree on sys.path, never installed: no version to claim
    __version__ = "0+unknown"
