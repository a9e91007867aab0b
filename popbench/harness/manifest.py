"""What made an output folder: the command, package versions, hardware and git commit."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

_PACKAGES = (
    "popbench",
    "numpy",
    "scipy",
    "torch",
    "torchrl",
    "tensordict",
    "torch-geometric",
    "pymetis",
    "pandas",
    "matplotlib",
)


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            cwd=Path(__file__).resolve().parent,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def write_manifest(
    folder: str | Path,
    command: list[str] | None = None,
    wall_s: float | None = None,
    execution: dict[str, Any] | None = None,
) -> Path:
    """Write ``manifest.json`` into ``folder`` and return its path; ``wall_s`` is the time of
    the invocation that wrote it (cells reused from the cache cost nothing); ``execution`` how
    its cells ran (:func:`popbench.harness.runner.execution_summary`)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    manifest = {
        "command": " ".join(command if command is not None else ["popbench", *sys.argv[1:]]),
        "written": datetime.now(UTC).isoformat(timespec="seconds"),
        "wall_s": None if wall_s is None else round(wall_s, 1),
        "execution": execution,
        "git_commit": _git_commit(),
        "python": platform.python_version(),
        "packages": {name: _version(name) for name in _PACKAGES},
        "hardware": {
            "cpu": _cpu_model(),
            "cores": os.cpu_count(),
            "machine": platform.machine(),
            "system": platform.platform(),
        },
    }
    path = folder / "manifest.json"
    path.write_text(json.dumps(manifest, indent=2) + "\n")
    return path
