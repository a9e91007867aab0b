"""Finished table cells, one JSON file each, so an interrupted run resumes where it stopped.

A cell is identified by the canonical JSON of its specification (experiment, dataset, robots,
method, seed, iterations, initial estimate, options); its file name is a hash of that JSON and
the file holds both the specification and the measured row.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any


def cell_key(spec: Mapping[str, Any]) -> str:
    """A stable 16-hex-digit key of a cell specification."""
    canonical = json.dumps(spec, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


class CellCache:
    """A folder of finished cells: ``<folder>/<key>.json`` holding ``{"spec": ..., "row": ...}``."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def _path(self, spec: Mapping[str, Any]) -> Path:
        return self.folder / f"{cell_key(spec)}.json"

    def get(self, spec: Mapping[str, Any]) -> dict[str, Any] | None:
        """The cached row of ``spec``, or None if the cell has not finished."""
        path = self._path(spec)
        if not path.exists():
            return None
        try:
            return json.loads(path.read_text())["row"]
        except (json.JSONDecodeError, KeyError):
            return None  # a torn write from an older interrupted run: recompute it

    def put(self, spec: Mapping[str, Any], row: Mapping[str, Any]) -> None:
        """Store a finished cell atomically (write a temporary file, then rename)."""
        path = self._path(spec)
        temporary = path.with_suffix(".tmp")
        temporary.write_text(json.dumps({"spec": spec, "row": row}, indent=1, default=float))
        os.replace(temporary, path)
