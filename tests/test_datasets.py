"""The dataset registry: pinned checksums, lookup order, offline or tampered files, ground truth."""

from __future__ import annotations

import dataclasses
import os
import shutil
import urllib.error
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import data_missing, dataset_missing, require_dataset

from popbench import datasets
from popbench.errors import DatasetError

SHARED = Path(__file__).resolve().parents[2] / "shared" / "datasets"
CONFIGURED = os.environ.get("POPBENCH_DATA")  # read before any test changes it
PAPER_DATASETS = ["intel", "mit", "csail", "m3500", "m3500a", "m3500b", "m3500c", "city10k"]
FILES = [name for name, entry in datasets.DATASETS.items() if entry.alias_of is None]


def source_dir() -> Path:
    """A folder holding the registered files: POPBENCH_DATA, else the team's shared copy."""
    if CONFIGURED and (Path(CONFIGURED) / "mit.g2o").is_file():
        return Path(CONFIGURED)
    if (SHARED / "mit.g2o").is_file():
        return SHARED
    data_missing("no local dataset folder (set POPBENCH_DATA)")


@pytest.fixture
def offline(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(url: str):
        raise urllib.error.URLError("network is unreachable")

    monkeypatch.setattr(datasets, "_open_url", refuse)


@pytest.fixture
def data_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """POPBENCH_DATA pointing at a private copy of mit.g2o; the cache is empty."""
    folder = tmp_path / "data"
    folder.mkdir()
    shutil.copy(source_dir() / "mit.g2o", folder / "mit.g2o")
    monkeypatch.setenv("POPBENCH_DATA", str(folder))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return folder


def test_registry_covers_the_paper_and_links_ground_truth() -> None:
    for name in [*PAPER_DATASETS, "grid1000", *(f"grid1000_{k}" for k in range(1, 6))]:
        assert name in datasets.DATASETS
    truth = {name: entry.ground_truth for name, entry in datasets.DATASETS.items()}
    assert {truth[m] for m in ("m3500", "m3500a", "m3500b", "m3500c")} == {"m3500_gt"}
    assert truth["city10k"] == "city10k_gt"
    assert {truth[f"grid1000_{k}"] for k in range(1, 6)} == {"grid1000_gt"}
    assert truth["intel"] is truth["mit"] is truth["csail"] is None
    alias = datasets.DATASETS["grid1000"]
    assert alias.alias_of == "grid1000_3"
    assert (alias.filename, alias.sha256) == (
        "grid1000_3.g2o",
        datasets.DATASETS["grid1000_3"].sha256,
    )


def test_registry_matches_the_pinned_checksum_list() -> None:
    sums = source_dir() / "SHA256SUMS"
    if not sums.is_file():
        data_missing(f"{sums} not found")
    pinned = dict(reversed(line.split()) for line in sums.read_text().splitlines())
    registered = {e.filename: e.sha256 for e in datasets.DATASETS.values()}
    shared = {e.filename: e.sha256 for e in datasets.DATASETS.values() if e.shared_copy}
    assert {f: registered.get(f) for f in pinned} == pinned  # every shared file is registered
    assert shared.items() <= pinned.items()  # and every record claiming a shared copy has one
    for entry in datasets.DATASETS.values():
        assert entry.url.startswith("https://raw.githubusercontent.com/")


@pytest.mark.dataset
@pytest.mark.parametrize("name", FILES)
def test_every_registered_file_verifies(monkeypatch: pytest.MonkeyPatch, name: str) -> None:
    monkeypatch.setenv("POPBENCH_DATA", str(source_dir()))
    status = dict(datasets.verify([name]))[name]
    if status == "missing":
        dataset_missing(name, datasets.DatasetUnavailableError(f"{name} missing"))
    assert status == "ok"


@pytest.mark.dataset
def test_a_packaged_copy_is_found_offline_and_verified(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, offline: None
) -> None:
    """w10000 comes from GTSAM's wheel (a test dependency) when no data folder holds it; a
    packaged copy with other bytes is refused like any other file."""
    monkeypatch.setenv("POPBENCH_DATA", str(tmp_path / "empty"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    try:
        path = datasets.dataset_path("w10000")
    except datasets.DatasetUnavailableError as error:
        data_missing(f"gtsam's w10000.graph unavailable: {error}")
    assert path.parts[-3:] == ("gtsam", "Data", "w10000.graph")
    package = tmp_path / "site" / "fakedata"
    (package / "Data").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "Data" / "w.graph").write_bytes(path.read_bytes()[:-1])
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    fake = dataclasses.replace(datasets.DATASETS["w10000"], packaged=("fakedata", "Data/w.graph"))
    monkeypatch.setitem(datasets.DATASETS, "w10000", fake)
    assert datasets.find("w10000") == package / "Data" / "w.graph"
    with pytest.raises(DatasetError, match=r"checksum mismatch .*\(dataset w10000\)"):
        datasets.dataset_path("w10000")
    monkeypatch.setitem(datasets.DATASETS, "w10000", dataclasses.replace(fake, packaged=None))
    with pytest.raises(datasets.DatasetUnavailableError, match="network is unreachable"):
        datasets.dataset_path("w10000")


def test_data_dir_and_cache(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("POPBENCH_DATA", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert datasets.data_dir() == tmp_path / "popbench"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert datasets.data_dir() == Path.home() / ".cache" / "popbench"
    monkeypatch.setenv("POPBENCH_DATA", str(tmp_path / "d"))
    assert datasets.search_dirs() == [tmp_path / "d", Path.home() / ".cache" / "popbench"]


def test_file_found_in_the_cache_when_not_in_popbench_data(
    data_copy: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, offline: None
) -> None:
    cache = tmp_path / "cache" / "popbench"
    cache.mkdir(parents=True)
    (data_copy / "mit.g2o").rename(cache / "mit.g2o")
    assert datasets.dataset_path("mit") == cache / "mit.g2o"


def test_wrong_checksum_names_the_file_and_the_fix(data_copy: Path) -> None:
    with (data_copy / "mit.g2o").open("a") as handle:
        handle.write("# one extra byte or more\n")
    with pytest.raises(DatasetError) as caught:
        datasets.dataset_path("mit")
    message = str(caught.value)
    assert str(data_copy / "mit.g2o") in message
    assert "expected sha256 e5922be0d068" in message
    assert "delete the file" in message and "popbench datasets fetch mit" in message
    assert not isinstance(caught.value, datasets.DatasetUnavailableError)
    assert dict(datasets.verify(["mit"]))["mit"].startswith("checksum mismatch")


def test_unknown_name_lists_the_known_ones() -> None:
    with pytest.raises(DatasetError, match="unknown dataset 'mitt'; known datasets: intel, mit"):
        datasets.load("mitt")
    with pytest.raises(DatasetError, match="city10k_gt"):
        datasets.dataset_path("nope")
    with pytest.raises(DatasetError, match="unknown dataset"):
        datasets.verify(["nope"])


def test_missing_path_is_a_dataset_error(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no such file"):
        datasets.load(tmp_path / "absent.g2o")


def test_missing_and_offline_says_what_to_do(data_copy: Path, offline: None) -> None:
    with pytest.raises(datasets.DatasetUnavailableError) as caught:
        datasets.dataset_path("intel")
    message = str(caught.value)
    assert "network is unreachable" in message
    assert "POPBENCH_DATA" in message and "popbench datasets fetch intel" in message
    assert list(data_copy.iterdir()) == [data_copy / "mit.g2o"]  # no partial file left behind
    with pytest.raises(datasets.DatasetUnavailableError, match="is not in"):
        datasets.dataset_path("intel", download=False)
    assert dict(datasets.verify(["intel", "mit"])) == {"intel": "missing", "mit": "ok"}


class FakeResponse:
    """What urlopen returns, serving fixed bytes."""

    def __init__(self, payload: bytes) -> None:
        self.payload = payload
        self.headers = {"Content-Length": str(len(payload))}

    def read(self, size: int) -> bytes:
        chunk, self.payload = self.payload[:size], self.payload[size:]
        return chunk

    def __enter__(self) -> FakeResponse:
        return self

    def __exit__(self, *exc: object) -> None:
        return None


def test_download_verifies_then_renames(
    data_copy: Path, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    payload = (source_dir() / "intel.g2o").read_bytes()
    requested = []

    def serve(url: str) -> FakeResponse:
        requested.append(url)
        return FakeResponse(payload)

    monkeypatch.setattr(datasets, "_open_url", serve)
    path = datasets.dataset_path("intel")
    assert path == data_copy / "intel.g2o" and path.read_bytes() == payload
    assert requested == [datasets.DATASETS["intel"].url]


def test_corrupt_download_is_not_saved(data_copy: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(datasets, "_open_url", lambda url: FakeResponse(b"<html>404</html>"))
    with pytest.raises(DatasetError, match="does not match the pinned checksum of dataset intel"):
        datasets.dataset_path("intel")
    assert sorted(p.name for p in data_copy.iterdir()) == ["mit.g2o"]


def test_checksum_is_cached_by_size_and_mtime(data_copy: Path) -> None:
    path = data_copy / "mit.g2o"
    first = datasets.file_sha256(path)
    assert datasets.file_sha256(path) == first == datasets.DATASETS["mit"].sha256
    path.write_bytes(path.read_bytes()[:-1])  # size changes: hashed again
    assert datasets.file_sha256(path) != first


@pytest.mark.dataset
def test_load_attaches_ground_truth_and_name() -> None:
    m3500a = require_dataset("m3500a")
    truth = require_dataset("m3500_gt")
    assert m3500a.name == "m3500a" and m3500a.ground_truth is not None
    np.testing.assert_array_equal(m3500a.ground_truth, truth.poses)
    assert m3500a.num_edges == 5453  # the ground-truth file's 5598 edges are not used
    grid = require_dataset("grid1000")
    assert grid.name == "grid1000" and grid.ground_truth.shape == (1000, 3)
    np.testing.assert_array_equal(grid.poses, require_dataset("grid1000_3").poses)
    assert require_dataset("intel").ground_truth is None


@pytest.mark.dataset
def test_registered_counts_match_the_files() -> None:
    for name in [*PAPER_DATASETS, "grid1000_5", "csail_toro"]:
        graph = require_dataset(name)
        entry = datasets.DATASETS[name]
        assert (graph.num_poses, graph.num_edges) == (entry.poses, entry.edges), name


@pytest.mark.dataset
@pytest.mark.parametrize("name", ["fr079", "frh", "w10000"])
def test_the_toro_datasets_load_with_their_counts(name: str) -> None:
    """FR079 and FRH (Carlone's TORO files) and w10000 (EQUIV lines merged on reading)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        graph = require_dataset(name)
    entry = datasets.DATASETS[name]
    assert (graph.num_poses, graph.num_edges) == (entry.poses, entry.edges)
    merged = [str(w.message) for w in caught if "EQUIV merged" in str(w.message)]
    if name == "w10000":  # 10000 poses and 64311 edges in the file
        assert "EQUIV merged 5875 vertex pair(s); dropped 13935 edge(s)" in merged[0]
    else:
        assert not merged


def test_load_reads_a_path(tmp_path: Path, small_graph) -> None:
    from popbench.io import write_g2o

    write_g2o(small_graph, tmp_path / "loop.g2o")
    graph = datasets.load(str(tmp_path / "loop.g2o"))
    assert graph.name == "loop" and graph.ground_truth is None
