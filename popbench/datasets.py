"""The registry of the paper's datasets: pinned URLs, sha256 checksums, local lookup, download.

Files are looked up, by their registered file name, in ``$POPBENCH_DATA`` (when set), then in
the per-user cache (``$XDG_CACHE_HOME/popbench`` or ``~/.cache/popbench``), then, for a record
that names one (``packaged``), in an installed Python package that ships the same file (GTSAM's
wheel ships ``w10000.graph``; the package is located, not imported). A missing file is
downloaded from its pinned raw GitHub URL into :func:`data_dir` (a temporary file, verified, then
renamed into place), so a half-written or tampered file is never used. Every file, wherever it
was found, is verified against its sha256 before it is read; a verification is remembered per
(path, size, mtime) for the life of the process.

``grid1000`` is an alias for ``grid1000_3``: the paper does not say which of the five Grid1000
noise levels it used (its table gives only 1000 poses / 1250 edges). Level 3 is the middle one
(σw = 3.2e-4, per-edge standard deviation ≈ 0.042 m / 0.042 rad): its residuals at the ground truth
agree with its information (g2o χ² 3905 for 3m = 3750), unlike level 5 (6086), and its odometry
drift (up to 9 m) makes a non-trivial initial guess, unlike level 1.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import os
import tempfile
import urllib.error
import urllib.request
from collections.abc import Iterable
from pathlib import Path

from popbench.errors import DatasetError
from popbench.graph import PoseGraph

_RAW = "https://raw.githubusercontent.com"
_DPGO = f"{_RAW}/mit-acl/dpgo/a238090c6427ad509370bd6c302bcac82c1be95f/data"
_CPL = f"{_RAW}/fantaosha/CPL-SLAM/c04d686594c318323568e596d0b6c62f15ea7697/data/2D"
_VERTIGO = f"{_RAW}/OpenSLAM-org/openslam_vertigo/e57e88cbc1756070f37c6c32f87be947e7a72bb8"
_UF = f"{_RAW}/corelabuf/planar_pgo_datasets/52d8cdce240d3d11ebf1e8936c0e56195a951637/datasets"
_SESYNC = f"{_RAW}/david-m-rosen/SE-Sync/9b631b6b82d8aa7d32ab846412ae1c070412b7b6/data"
_APEX = f"{_RAW}/amin-abouee/apex-solver/8ddabc07c0f3b75bceca6893246beb42a5fe19ed/data"
_GTSAM = f"{_RAW}/borglab/gtsam/0ffe6c930302ebd297484e65e6e8d467c91d26b0/examples/Data"
_DOWNLOAD_TIMEOUT_S = 30.0
_CHUNK_BYTES = 1 << 16


@dataclasses.dataclass(frozen=True)
class Dataset:
    """One registered file.

    Attributes:
        name: registry key (``popbench solve NAME``).
        filename: file name inside the data directory (may contain a sub-folder).
        url: pinned raw URL whose bytes hash to ``sha256``.
        sha256: hex digest of the file.
        poses, edges: counts from parsing the file.
        description: one line for ``popbench datasets list``.
        ground_truth: name of the registered file whose VERTEX lines are the true poses, or None.
        alias_of: the registered name this entry duplicates, or None.
        packaged: ``(package, path inside it)`` of an installed Python package that ships the
            same bytes, searched after the data folders, or None.
        chordal_optimum: ``F_chordal*`` (SE-Sync's convention) of the file: SE-Sync's certified
            optimum (Rosen et al. 2019, Table 1) or centralised LM's from the chordal start, which
            reproduces every certified value; the floor of the baselines' benchmarks and tests.
            None: not recorded.
        shared_copy: whether the team's data folder (``shared/datasets``, POPBENCH_DATA in the
            tests and CI, which have no network) holds the file. A record with neither a shared
            copy nor ``packaged`` is not expected offline: the tests skip it, naming it, when
            it is missing (tests/conftest.py).
    """

    name: str
    filename: str
    url: str
    sha256: str
    poses: int
    edges: int
    description: str
    ground_truth: str | None = None
    alias_of: str | None = None
    packaged: tuple[str, str] | None = None
    chordal_optimum: float | None = None
    shared_copy: bool = True


def _grid_level(level: int, sha256: str, sigma_w: str) -> Dataset:
    return Dataset(
        f"grid1000_{level}",
        f"grid1000_{level}.g2o",
        f"{_UF}/Grid1000_{level}.g2o",
        sha256,
        1000,
        1250,
        f"Grid1000 (randomised Manhattan grid), noise level {level} (σw={sigma_w})",
        ground_truth="grid1000_gt",
    )


_GRID_LEVELS = [
    _grid_level(1, "31b3e36c11c299c16ef745c48316a7d6fcfd65e54f1396b78233faa6186d5f40", "1.0e-5"),
    _grid_level(2, "cda38e719f7d2741edfe9b893983a8f74c10fb30c65a3b43d3836d00e2f47437", "5.6e-5"),
    _grid_level(3, "7e238a1bffe583b1c86790fc9c4e560b186c5671ed2c6ef9c189fe1539708a1a", "3.2e-4"),
    _grid_level(4, "c555aba463bef8583c10ad869b1f64bb1a535cec4bb2ae210e97e13722c966e9", "1.8e-3"),
    _grid_level(5, "704cf0f4d42e903b845817d16af6c4c8a7b2b6548877fbf8adf07b91aef6dca7", "1.0e-2"),
]
GRID1000_DEFAULT_LEVEL = 3

_ENTRIES = [
    Dataset(
        "intel",
        "intel.g2o",
        f"{_DPGO}/input_INTEL_g2o.g2o",
        "e648e42b1f24ab01cce76f56c8d8dad0b606f712afe2b92356bf26f195c602be",
        1228,
        1483,
        "Intel Research Lab (Carlone's g2o version), real data",
        chordal_optimum=393.6525,
    ),
    Dataset(
        "mit",
        "mit.g2o",
        f"{_DPGO}/input_MITb_g2o.g2o",
        "e5922be0d0689c7a5bc04c58adf3a8e697e240bdd7691cc4218470eaf92956eb",
        808,
        827,
        "MIT Killian Court (MITb), real data; 20 loop closures written i > j",
        chordal_optimum=61.1541,
    ),
    Dataset(
        "csail",
        "csail.g2o",
        f"{_SESYNC}/CSAIL.g2o",
        "66d99ac857a9849d814d214a9ebd0d4876d5d40f0a37be9330c1ff6e6e9daaa6",
        1045,
        1172,
        "CSAIL (SE-Sync's g2o form of Carlone's TORO file), real data; edges only",
        chordal_optimum=31.7037,
    ),
    Dataset(
        "m3500",
        "m3500.g2o",
        f"{_DPGO}/input_M3500_g2o.g2o",
        "1883593980e602b11bd0ba95799c969e59ee8a6892bdb2a3a48f495459efe9d8",
        3500,
        5453,
        "M3500 (Olson's simulated Manhattan world, Carlone's g2o version)",
        chordal_optimum=193.8623,
        ground_truth="m3500_gt",
    ),
    Dataset(
        "m3500a",
        "m3500a.g2o",
        f"{_CPL}/M3500a.g2o",
        "34deb00c3ff7206048d805c612c545cd8764ac3a7fd933a4ee2d3419fc3a0b8f",
        3500,
        5453,
        "M3500 with extra rotation noise σ=0.1 rad",
        ground_truth="m3500_gt",
    ),
    Dataset(
        "m3500b",
        "m3500b.g2o",
        f"{_CPL}/M3500b.g2o",
        "55342238a0d45d724ce590202f4c3ad3004e02c3d770e029677030b50a632f48",
        3500,
        5453,
        "M3500 with extra rotation noise σ=0.2 rad",
        ground_truth="m3500_gt",
    ),
    Dataset(
        "m3500c",
        "m3500c.g2o",
        f"{_CPL}/M3500c.g2o",
        "01c8a6b505e63386d5d12fbb1d6aadb95f564294e6e3805eb8accf6aaa6b656e",
        3500,
        5453,
        "M3500 with extra rotation noise σ=0.3 rad",
        ground_truth="m3500_gt",
    ),
    Dataset(
        "city10k",
        "city10k.g2o",
        f"{_VERTIGO}/datasets/city10000/originalDataset/city10000.g2o",
        "df5988994339e990be198a36e7f640e31a5a1b26df3ed400363fafc49d5ca630",
        10000,
        20687,
        "City10000 (Kaess, iSAM), simulated",
        ground_truth="city10k_gt",
        chordal_optimum=638.6246,
    ),
    dataclasses.replace(
        _GRID_LEVELS[GRID1000_DEFAULT_LEVEL - 1],
        name="grid1000",
        description=f"alias of grid1000_{GRID1000_DEFAULT_LEVEL}, the middle noise level "
        "(the paper does not name its level)",
        alias_of=f"grid1000_{GRID1000_DEFAULT_LEVEL}",
    ),
    *_GRID_LEVELS,
    Dataset(
        "m3500_gt",
        "m3500_gt.g2o",
        f"{_UF}/M3500_ground_truth.g2o",
        "955a422e17a4946a699155b37f120b8b1cf034085cc4f7fc19813f1f0972bc08",
        3500,
        5598,
        "M3500 ground truth (Olson), for m3500 and m3500a/b/c; do not optimise",
    ),
    Dataset(
        "city10k_gt",
        "city10k_gt.g2o",
        f"{_UF}/city10000_ground_truth.g2o",
        "45b1760addc40c561649a1bec38b65dee2ea32a9ba9ce6271bd1db83cf95d438",
        10000,
        20687,
        "City10000 ground truth; do not optimise",
    ),
    Dataset(
        "grid1000_gt",
        "grid1000_gt.g2o",
        f"{_UF}/Grid1000_ground_truth.g2o",
        "b3b11f016de9782a812ae8bdcf36642b7b0647d5b917c0ab9f24d2a24a486022",
        1000,
        1250,
        "Grid1000 ground truth (placeholder information); do not optimise",
    ),
    Dataset(
        "csail_toro",
        "toro/csail_toro.graph",
        f"{_APEX}/CSAIL_P_toro.graph",
        "fcf4de76b262e7f58ea64b8c5db806fec926a519d2f5d85fcc9c553f8f82fa98",
        1045,
        1172,
        "CSAIL, Carlone's original TORO file (same cost as csail)",
    ),
    Dataset(
        "fr079",
        "toro/fr079_toro.graph",
        f"{_APEX}/FR079_P_toro.graph",
        "ba53624ae4ed843258359c8e5713e7456943b6daf2e4a17b800a90e170d7e659",
        989,
        1217,
        "FR079 (Freiburg building 079), Carlone's TORO file FR079_P_toro, real data",
        shared_copy=False,
    ),
    Dataset(
        "frh",
        "toro/frh_toro.graph",
        f"{_APEX}/FRH_P_toro.graph",
        "56868ab910e876e358ab74478c55f48aa6275bd133739f927510e442b3a523ee",
        1316,
        2820,
        "FRH (Freiburg hospital), Carlone's TORO file FRH_P_toro, real data",
        shared_copy=False,
    ),
    Dataset(
        "w10000",
        "toro/w10000.graph",
        f"{_GTSAM}/w10000.graph",
        "1e88f220bd580a4c2b9fc065358608a53b26b1c30033405990b4cdc83236fc89",
        4125,
        50376,
        "W10000 (Olson's simulated world, GTSAM's example; not City10000): 10000 poses and "
        "64311 edges in the file, 5875 EQUIV lines merge them to these counts",
        packaged=("gtsam", "Data/w10000.graph"),
        shared_copy=False,
    ),
]

DATASETS: dict[str, Dataset] = {entry.name: entry for entry in _ENTRIES}


class DatasetUnavailableError(DatasetError):
    """A registered file that is neither on disk nor downloadable (offline, unwritable folder)."""


def data_dir() -> Path:
    """Where downloads go: ``$POPBENCH_DATA`` if set, else the per-user cache folder."""
    configured = os.environ.get("POPBENCH_DATA")
    return Path(configured).expanduser() if configured else cache_dir()


def cache_dir() -> Path:
    """The per-user cache: ``$XDG_CACHE_HOME/popbench``, else ``~/.cache/popbench``."""
    root = os.environ.get("XDG_CACHE_HOME")
    return (Path(root) if root else Path.home() / ".cache") / "popbench"


def search_dirs() -> list[Path]:
    """Folders searched for a registered file, in order: ``$POPBENCH_DATA`` then the cache."""
    return list(dict.fromkeys([data_dir(), cache_dir()]))


def get(name: str) -> Dataset:
    """The registered :class:`Dataset` called ``name``.

    Raises:
        DatasetError: unknown name (the message lists the known ones).
    """
    if name not in DATASETS:
        raise _unknown(name)
    return DATASETS[name]


def _unknown(name: str) -> DatasetError:
    return DatasetError(
        f"unknown dataset {name!r}; known datasets: {', '.join(DATASETS)} "
        "(or give a path to a .g2o/.graph file)"
    )


# (resolved path, size, mtime_ns) -> sha256 hex digest of files already hashed by this process.
_verified: dict[tuple[str, int, int], str] = {}


def file_sha256(path: Path) -> str:
    """Hex sha256 of ``path``, remembered by (path, size, mtime) so repeated calls are cheap."""
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _verified:
        digest = hashlib.sha256()
        with path.open("rb") as handle:
            for chunk in iter(lambda: handle.read(_CHUNK_BYTES), b""):
                digest.update(chunk)
        _verified[key] = digest.hexdigest()
    return _verified[key]


def _check(dataset: Dataset, path: Path) -> None:
    actual = file_sha256(path)
    if actual != dataset.sha256:
        raise DatasetError(
            f"checksum mismatch for {path} (dataset {dataset.name}): expected sha256 "
            f"{dataset.sha256[:12]}…, got {actual[:12]}…; delete the file and re-fetch it with "
            f"`popbench datasets fetch {dataset.name}`"
        )


def find(name: str) -> Path | None:
    """The first existing copy of ``name``'s file in :func:`search_dirs`, else in its record's
    ``packaged`` source (:func:`packaged_path`); unverified; or None."""
    dataset = get(name)
    for folder in search_dirs():
        candidate = folder / dataset.filename
        if candidate.is_file():
            return candidate
    return packaged_path(dataset)


def packaged_path(dataset: Dataset) -> Path | None:
    """The file ``dataset.packaged`` names inside its installed package (located with
    ``importlib.util.find_spec``, not imported), or None when it has none or it is missing."""
    if dataset.packaged is None:
        return None
    package, inside = dataset.packaged
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        return None
    for folder in (spec.submodule_search_locations or []) if spec else []:
        candidate = Path(folder) / inside
        if candidate.is_file():
            return candidate
    return None


def dataset_path(name: str, download: bool = True) -> Path:
    """The verified local file of the registered dataset ``name``, downloading it if missing.

    Raises:
        DatasetError: unknown name or checksum mismatch.
        DatasetUnavailableError: missing and ``download`` is False, or the download failed.
    """
    dataset = get(name)
    path = find(name)
    if path is None:
        if not download:
            raise DatasetUnavailableError(_missing_message(dataset))
        path = _download(dataset, data_dir() / dataset.filename)
    _check(dataset, path)
    return path


def _missing_message(dataset: Dataset, reason: str = "") -> str:
    folders = " or ".join(str(folder) for folder in search_dirs())
    if dataset.packaged is not None:
        folders += f" or the installed package {dataset.packaged[0]}"
    return (
        f"dataset {dataset.name} ({dataset.filename}) is not in {folders}{reason}; set "
        f"POPBENCH_DATA to a folder holding it, or run `popbench datasets fetch {dataset.name}` "
        "while online"
    )


def _open_url(url: str):  # -> the urllib response (a context manager)
    """Open ``url`` for reading (a seam for tests that simulate being offline)."""
    return urllib.request.urlopen(url, timeout=_DOWNLOAD_TIMEOUT_S)


def _download(dataset: Dataset, target: Path) -> Path:
    """Stream ``dataset.url`` into a temporary file beside ``target`` with a progress bar,
    verify its sha256 and rename it into place (atomic on one file system)."""
    from tqdm import tqdm

    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        handle = tempfile.NamedTemporaryFile(
            dir=target.parent, prefix=f".{target.name}.", suffix=".part", delete=False
        )
    except OSError as error:
        reason = f" and {target.parent} is not writable ({error.strerror})"
        raise DatasetUnavailableError(_missing_message(dataset, reason)) from None
    partial = Path(handle.name)
    digest = hashlib.sha256()
    try:
        with handle, _open_url(dataset.url) as response:
            size = response.headers.get("Content-Length")
            with tqdm(
                total=int(size) if size else None,
                unit="B",
                unit_scale=True,
                desc=f"fetch {dataset.name}",
                disable=None,  # no bar when stderr is not a terminal
            ) as bar:
                for chunk in iter(lambda: response.read(_CHUNK_BYTES), b""):
                    handle.write(chunk)
                    digest.update(chunk)
                    bar.update(len(chunk))
        if digest.hexdigest() != dataset.sha256:
            raise DatasetError(
                f"downloaded {dataset.url} does not match the pinned checksum of dataset "
                f"{dataset.name} (expected sha256 {dataset.sha256[:12]}…, got "
                f"{digest.hexdigest()[:12]}…); nothing was saved"
            )
        os.replace(partial, target)
    except (urllib.error.URLError, OSError) as error:
        reason = getattr(error, "reason", None) or getattr(error, "strerror", None) or error
        message = _missing_message(dataset, f" and downloading {dataset.url} failed ({reason})")
        raise DatasetUnavailableError(message) from None
    finally:
        partial.unlink(missing_ok=True)
    return target


def fetch(name: str) -> Path:
    """Download ``name`` (and its ground-truth file) if missing and verify; the local path."""
    dataset = get(name)
    if dataset.ground_truth is not None:
        dataset_path(dataset.ground_truth)
    return dataset_path(name)


def verify(names: Iterable[str] | None = None) -> list[tuple[str, str]]:
    """Check local files without downloading: ``(name, status)`` with status ``"ok"``,
    ``"missing"`` or ``"checksum mismatch: …"``. Default: every registered non-alias name."""
    if names is None:
        names = [name for name, entry in DATASETS.items() if entry.alias_of is None]
    names = [get(name).name for name in names]  # unknown names raise before any work
    report = []
    for name in names:
        try:
            dataset_path(name, download=False)
            status = "ok"
        except DatasetUnavailableError:
            status = "missing"
        except DatasetError as error:
            status = f"checksum mismatch: {error}"
        report.append((name, status))
    return report


def load(name_or_path: str | Path) -> PoseGraph:
    """A registered dataset by name, or a ``.g2o``/``.graph`` file by path, as a PoseGraph.

    Registered datasets carry their name and, where a ``*_gt`` file exists, the ground-truth
    poses (the VERTEX lines of that file; its edges are not used).

    Raises:
        DatasetError: unknown name, missing file or checksum mismatch.
        DataFormatError: a malformed file.
    """
    from popbench.io import read_graph, read_vertices

    key = str(name_or_path)
    if key in DATASETS:
        dataset = DATASETS[key]
        graph = read_graph(dataset_path(key), name=key)
        if dataset.ground_truth is None:
            return graph
        truth = read_vertices(dataset_path(dataset.ground_truth))
        if truth.shape != graph.poses.shape:
            raise DatasetError(
                f"ground truth {dataset.ground_truth} has {truth.shape[0]} poses, "
                f"dataset {key} has {graph.num_poses}"
            )
        return graph.replace(ground_truth=truth)
    path = Path(name_or_path).expanduser()
    if path.is_file():
        return read_graph(path)
    if path.exists():
        raise DatasetError(f"not a pose-graph file: {path}")
    if path.suffix or os.sep in key:
        raise DatasetError(f"no such file: {path}")
    raise _unknown(key)
