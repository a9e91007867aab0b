"""Errors that reach the user as one line (the CLI prints ``str(error)`` and exits non-zero)."""

from __future__ import annotations

from pathlib import Path


class PopbenchError(Exception):
    """Base class: an error whose message is a complete, one-line explanation for the user."""


class DataFormatError(PopbenchError):
    """A malformed pose-graph file, located by file and line."""

    def __init__(self, path: str | Path, line: int, message: str) -> None:
        super().__init__(f"{path}:{line}: {message}")
        self.path = Path(path)
        self.line = line


class DatasetError(PopbenchError):
    """An unknown dataset, a missing file or a checksum mismatch."""


class ValueRangeError(PopbenchError):
    """An option value outside its allowed range."""

    def __init__(self, name: str, value: object, allowed: str) -> None:
        super().__init__(f"invalid {name} {value!r}: allowed {allowed}")
        self.name = name
        self.value = value
