"""Finished table cells, one JSON file each, so an interrupted run resumes where it stopped.

A cell is identified by the canonical JSON of its specification (experiment, dataset, robots,
method, seed, iterations, initial estimate, options) and of what it was computed from: the
sha256 of the dataset file (:func:`dataset_sha256`), the code (:func:`code_fingerprint`) and,
for the learned methods, the sha256 of the actor checkpoint (:func:`checkpoint_sha256`). Its
file name is a hash of that JSON and the file holds both the specification and the measured
row. A changed input file, code or checkpoint therefore gives a new key and the cell is
recomputed; the old file is left in the folder, unused.

A cell of a method that another refines (:mod:`popbench.harness.refining`) also keeps its whole
:class:`~popbench.methods.Result` in ``<key>.result.npz`` (poses, history and its times, inlier
mask, and the scalars and extras as JSON), which the refiner's cell starts from; the refiner's
``wall_s`` and ``parallel_s`` are the refined method's cached times plus the refinement's own.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
from collections.abc import Iterable, Mapping, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from popbench.methods import METHODS, Result, method_record, package_folder

# The packages whose code computes a cell: the core, the baselines, the agents and their envs.
CODE_PACKAGES = ("popbench", "baselines", "agents", "envs")


def cell_key(spec: Mapping[str, Any]) -> str:
    """A stable 16-hex-digit key of a cell specification."""
    canonical = json.dumps(spec, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(canonical.encode()).hexdigest()[:16]


def source_fingerprint(folders: Iterable[Path | None]) -> str:
    """sha256 (16 hex digits) of every ``*.py`` file under ``folders``: names and contents.

    Independent of git (a checkout with uncommitted edits, an sdist or a wheel all work) and
    unchanged by commits that touch only docs, results or tests.
    """
    digest = hashlib.sha256()
    for folder in folders:
        if folder is None:
            continue
        folder = Path(folder)
        for path in sorted(folder.rglob("*.py")):
            digest.update(f"{folder.name}/{path.relative_to(folder).as_posix()}\0".encode())
            digest.update(path.read_bytes())
            digest.update(b"\0")
    return digest.hexdigest()[:16]


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """``VERSION+SOURCEHASH``: the package version and :func:`source_fingerprint` of
    :data:`CODE_PACKAGES` (computed once per process; about 600 kB of source)."""
    from popbench import __version__

    return f"{__version__}+{source_fingerprint(package_folder(p) for p in CODE_PACKAGES)}"


def dataset_sha256(dataset: str) -> str:
    """sha256 of the file that :func:`popbench.datasets.load` reads for ``dataset``: the pinned
    checksum of a registered name (the loader refuses any other file), else the file's own."""
    from popbench import datasets

    if dataset in datasets.DATASETS:
        return datasets.DATASETS[dataset].sha256
    return datasets.file_sha256(Path(dataset).expanduser())


def checkpoint_path(method: str, training_seed: int = 0) -> Path | None:
    """The checkpoint file the registered ``method`` depends on for ``training_seed`` (its
    record's :meth:`~popbench.methods.MethodRecord.checkpoint_path`), or None."""
    return method_record(method).checkpoint_path(training_seed)


def checkpoint_sha256(method: str, training_seed: int = 0) -> str | None:
    """sha256 of :func:`checkpoint_path`, or None when there is no such file."""
    from popbench.datasets import file_sha256

    path = checkpoint_path(method, training_seed)
    return file_sha256(path) if path is not None and path.is_file() else None


def provenance(dataset: str, method: str | None = None, training_seed: int = 0) -> dict[str, Any]:
    """What a cell on ``dataset`` with ``method`` was computed from, for its specification
    (with the sha256 of the checkpoint of ``training_seed`` for a method whose record names
    one)."""
    inputs: dict[str, Any] = {"code": code_fingerprint(), "dataset_sha256": dataset_sha256(dataset)}
    if method in METHODS and METHODS[method].checkpoint is not None:
        inputs["checkpoint_sha256"] = checkpoint_sha256(method, training_seed)
    return inputs


def grid_specs(
    experiment: str,
    axes: Mapping[str, Sequence[Any]],
    shared: Mapping[str, Any],
    training_seeds: Sequence[int] = (0,),
) -> list[dict[str, Any]]:
    """One cell specification per point of the product of ``axes`` (in their order, the last
    varying fastest; they include ``dataset`` and ``method``): the point, the options every
    cell shares (``shared``) and what the cell is computed from (:func:`provenance`). A method
    whose record names a checkpoint gets one cell per ``training_seeds`` entry (its key
    ``training_seed``), each keyed by that seed's checkpoint; the others one cell."""
    specs = []
    for values in itertools.product(*axes.values()):
        point = dict(zip(axes, values, strict=True))
        method = point["method"]
        per_seed = method in METHODS and METHODS[method].checkpoint is not None
        for training_seed in training_seeds if per_seed else (None,):
            seeded = point if training_seed is None else {**point, "training_seed": training_seed}
            inputs = provenance(point["dataset"], method, training_seed or 0)
            specs.append({**inputs, "experiment": experiment, **seeded, **shared})
    return specs


class CellCache:
    """A folder of finished cells: ``<folder>/<key>.json`` holding ``{"spec": ..., "row": ...}``."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def _path(self, spec: Mapping[str, Any]) -> Path:
        return self.folder / f"{cell_key(spec)}.json"

    def _result_path(self, spec: Mapping[str, Any]) -> Path:
        return self.folder / f"{cell_key(spec)}.result.npz"

    def get(self, spec: Mapping[str, Any]) -> dict[str, Any] | None:
        """The cached row of ``spec``, or None if the cell has not finished."""
        path = self._path(spec)
        if not path.exists():
            return None
        try:
            return json.loads(path.read_text())["row"]
        except (json.JSONDecodeError, KeyError):
            return None  # a torn write from an older interrupted run: recompute it

    def measured(self, spec: Mapping[str, Any]) -> dict[str, Any] | None:
        """How the cached cell's time was measured (executor, jobs, cores, threads), or None
        (not cached, or cached before this was recorded)."""
        path = self._path(spec)
        try:
            return json.loads(path.read_text()).get("measured")
        except (OSError, json.JSONDecodeError, AttributeError):
            return None

    def put(
        self,
        spec: Mapping[str, Any],
        row: Mapping[str, Any],
        *,
        measured: Mapping[str, Any] | None = None,
    ) -> None:
        """Store a finished cell atomically (write a temporary file, then rename); ``measured``
        says how its time was measured. Safe from concurrent workers: the temporary file's name
        is unique to the writing process."""
        path = self._path(spec)
        temporary = path.with_suffix(f".{os.getpid()}.tmp")
        content: dict[str, Any] = {"spec": spec, "row": row}
        if measured is not None:
            content["measured"] = measured
        temporary.write_text(json.dumps(content, indent=1, default=float))
        os.replace(temporary, path)

    def put_result(self, spec: Mapping[str, Any], result: Result) -> None:
        """Store the whole :class:`~popbench.methods.Result` of ``spec`` atomically (arrays
        exactly, the scalars and ``extras`` as JSON), for a method that another refines."""
        path = self._result_path(spec)
        temporary = path.with_suffix(f".{os.getpid()}.tmp.npz")
        scalars = {
            field: getattr(result, field)
            for field in (
                "F",
                "F_chordal",
                "chi2",
                "wall_s",
                "parallel_s",
                "iterations",
                "messages",
            )
        }
        scalars["history_objective"] = result.history_objective
        arrays = {"poses": result.poses, "history": result.history}
        for name in ("inlier_mask", "history_s"):
            if getattr(result, name) is not None:
                arrays[name] = getattr(result, name)
        meta = json.dumps({"scalars": scalars, "extras": result.extras}, default=float)
        np.savez(temporary, **arrays, meta=np.array(meta))
        os.replace(temporary, path)

    def result(self, spec: Mapping[str, Any]) -> Result | None:
        """The cached :class:`~popbench.methods.Result` of ``spec`` (:meth:`put_result`), or
        None if there is none (or it is unreadable: recompute it)."""
        from popbench.methods import Result

        path = self._result_path(spec)
        if not path.exists():
            return None
        try:
            with np.load(path) as stored:
                meta = json.loads(str(stored["meta"]))
                optional = {
                    name: stored[name] if name in stored.files else None
                    for name in ("inlier_mask", "history_s")
                }
                return Result(
                    poses=stored["poses"],
                    history=stored["history"],
                    **optional,
                    extras=meta["extras"],
                    **meta["scalars"],
                )
        except (OSError, ValueError, KeyError, json.JSONDecodeError):
            return None

    def discard(self, spec: Mapping[str, Any]) -> None:
        """Forget the cell of ``spec``: its row and its result (if any)."""
        self._path(spec).unlink(missing_ok=True)
        self._result_path(spec).unlink(missing_ok=True)
