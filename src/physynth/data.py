"""The real recordings PhySynth calibrates on and scores trackers on, fetched from where they are published.

Two datasets, each a fixed commit of a public repository (not made by this project; cite them):

- ``hanyang-uwb``: the Hanyang University outdoor UWB dataset (ranges to four anchors, GNSS truth, static
  range sweeps), Apache-2.0;
- ``broad-imu``: four trials of the BROAD inertial benchmark (IMU with optical truth), CC BY 4.0.

Every file's SHA-256 ships with the package (``physynth/data_registry/<name>.txt``, in pooch's registry
format, written by ``tools/make_data_registry.py``). :func:`fetch` downloads the files that are missing or
damaged with `pooch <https://www.fatiando.org/pooch/>`_ (each to a temporary file in the target folder,
checked against its hash, then moved into place: a file that fails its check is never left as if good)
into the data root: the ``root`` argument, else ``PHYSYNTH_DATA_DIR``, else the user's cache
(``pooch.os_cache("physynth")``). A folder that already holds a copy (laid out as ``<root>/<name>/...``)
serves as the data root without any download. ``base_url`` (or ``PHYSYNTH_DATA_URL``) fetches from a
mirror instead of the upstream repositories: an HTTP(S) folder laid out like a data root
(``<base_url>/<name>/<path>``).

The library never prints: ``progress(message, done, total)`` counts files. Errors about the arguments are
:class:`~physynth.errors.PhySynthError` s; a download that fails is a :class:`DownloadError`.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from urllib.parse import quote

from .errors import ArgumentError, DatasetError, PhySynthError
from .progress import ProgressCallback, no_progress

DATA_DIR_ENV = "PHYSYNTH_DATA_DIR"
"""Environment variable: the data root (a folder holding one folder per dataset)."""
DATA_URL_ENV = "PHYSYNTH_DATA_URL"
"""Environment variable: a mirror to fetch from instead of the upstream repositories."""
REGISTRY_PACKAGE = "physynth.data_registry"
TIMEOUT_S = 60.0
"""Seconds to wait for a server before a download counts as failed."""


class DownloadError(PhySynthError):
    """A file could not be fetched: the server is unreachable, answered with an error, or sent bytes that
    fail their SHA-256 check. Nothing that failed is kept."""


@dataclass(frozen=True, slots=True, kw_only=True)
class Dataset:
    """A published dataset: what it is, its licence, how to cite it and where its files are."""

    name: str
    title: str
    description: str
    licence: str
    citation: str
    homepage: str
    base_url: str
    """Upstream folder of the files (a fixed commit): each file is at ``base_url + quoted path``."""

    def registry(self) -> dict[str, str]:
        """Every file of the dataset (path relative to the dataset folder) and its ``sha256:...`` hash."""
        return _read_registry(self.name)[0]

    @property
    def size_bytes(self) -> int:
        """Total size of the files, as recorded in the registry."""
        return _read_registry(self.name)[1]


_HANYANG_COMMIT = "c12599812e556324eadc763e409ea8f51098dda6"
_BROAD_COMMIT = "7e2f8189bb4a3ac91eae32c69b6bc87f08a6e2ad"

DATASETS: dict[str, Dataset] = {
    d.name: d
    for d in (
        Dataset(
            name="hanyang-uwb",
            title="Hanyang outdoor UWB dataset",
            description="outdoor UWB ranges to 4 anchors with RTK-GNSS truth (walks, LOS/NLOS) and static "
                        "range sweeps",
            licence="Apache-2.0",
            citation="ADIP laboratory, Hanyang University, \"Comprehensive outdoor UWB dataset: Static and "
                     "dynamic measurements in LOS/NLOS environments\", doi:10.5281/zenodo.15226105",
            homepage="https://github.com/cucudasluv/UWB-dataset",
            base_url=f"https://raw.githubusercontent.com/cucudasluv/UWB-dataset/{_HANYANG_COMMIT}/",
        ),
        Dataset(
            name="broad-imu",
            title="BROAD inertial benchmark (4 trials)",
            description="MEMS IMU moved by hand with optical motion-capture truth (BROAD trials 10, 15, 21, 24)",
            licence="CC-BY-4.0",
            citation="D. Laidig, M. Caruso, A. Cereatti, T. Seel, \"BROAD - A Benchmark for Robust Inertial "
                     "Orientation Estimation\", Data 6(7):72, 2021, doi:10.3390/data6070072",
            homepage="https://github.com/dlaidig/broad",
            base_url=f"https://raw.githubusercontent.com/dlaidig/broad/{_BROAD_COMMIT}/",
        ),
    )
}
"""The datasets :func:`fetch` knows, by name."""

HANYANG_TRAJECTORY_A_RUNS = ("LOS/Trajectory_A/Case_1", "LOS/Trajectory_A/Case_2", "NLOS/Trajectory_A/Case_1",
                             "NLOS/Trajectory_A/Case_2")
"""The four walks of ``hanyang-uwb`` the project calibrates and scores on (Trajectory_A, LOS and NLOS, two
cases each), as paths under the dataset's ``Dynamic_measurements`` folder, in this fixed order: the runs
of the shipped ``walk-hanyang`` preset and of the tracking study's default split (the last one is its test
run)."""


def hanyang_run_label(run: str) -> str:
    """The short label of a Hanyang run, without its trajectory: ``LOS/Case_1`` for ``LOS/Trajectory_A/Case_1``."""
    env, _trajectory, case = run.split("/")
    return f"{env}/{case}"


def list_datasets() -> list[Dataset]:
    """The datasets that can be fetched, in a fixed order."""
    return list(DATASETS.values())


def get_dataset(name: str) -> Dataset:
    """The dataset called ``name``; an unknown name is an :class:`~physynth.errors.ArgumentError`."""
    if not isinstance(name, str) or name not in DATASETS:
        raise ArgumentError(f"unknown dataset {name!r}; known: {', '.join(DATASETS)}")
    return DATASETS[name]


def data_root(root: str | os.PathLike | None = None) -> Path:
    """The folder holding one folder per dataset: ``root``, else ``PHYSYNTH_DATA_DIR``, else the user's cache."""
    if root is not None and str(root) != "":
        return Path(root).expanduser()
    env = os.environ.get(DATA_DIR_ENV, "")
    if env:
        return Path(env).expanduser()
    import pooch

    return Path(pooch.os_cache("physynth"))


def missing_files(name: str, root: str | os.PathLike | None = None,
                  registry: Mapping[str, str] | None = None) -> list[str]:
    """The files of dataset ``name`` (of ``registry`` if given) that are absent under the data root."""
    folder = data_root(root) / get_dataset(name).name
    files = _registry_of(name, registry)
    return [f for f in files if not (folder / f).is_file()]


def dataset_path(name: str, root: str | os.PathLike | None = None,
                 registry: Mapping[str, str] | None = None) -> Path:
    """The folder of dataset ``name`` under the data root, when every file of it is there.

    A dataset that is absent or incomplete is a :class:`~physynth.errors.DatasetError` naming it and the
    folder. The files are not hashed here (:func:`fetch` checks them).
    """
    ds = get_dataset(name)
    folder = data_root(root) / ds.name
    how = (f"fetch it with physynth.data.fetch('{ds.name}'), or set {DATA_DIR_ENV} to a folder that holds a "
           f"copy of it")
    if not folder.is_dir():
        raise DatasetError(f"dataset {ds.name} is not fetched (no folder {folder}): {how}")
    missing = missing_files(name, root, registry)
    if missing:
        total = len(_registry_of(name, registry))
        raise DatasetError(f"dataset {ds.name} is incomplete under {folder}: {len(missing)} of {total} files "
                           f"missing (first: {missing[0]}): {how}")
    return folder


@dataclass(frozen=True, slots=True)
class FetchResult:
    """What :func:`fetch` did: where the dataset is, and how many files it downloaded and found good."""

    path: Path
    downloaded: int
    verified: int


def fetch(name: str, root: str | os.PathLike | None = None, base_url: str | None = None,
          progress: ProgressCallback | None = None, registry: Mapping[str, str] | None = None,
          retries: int = 1) -> FetchResult:
    """Download every file of dataset ``name`` that is missing or fails its SHA-256 check into the data root.

    Files already present with the right hash are kept as they are (a complete local copy needs no
    network). ``base_url`` (else ``PHYSYNTH_DATA_URL``, else the upstream repository) is a mirror laid out
    like a data root: file ``p`` of the dataset is fetched from ``<base_url>/<name>/<p>``. ``registry``
    (path -> ``sha256:...``) restricts the fetch to those files (default: the shipped registry, every
    file). Each download goes to a temporary file beside its target and is moved into place only once its
    hash matches; a file that fails is tried ``retries`` more times, then a :class:`DownloadError` names it.
    """
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ArgumentError(f"retries must be a whole number >= 0, not {retries!r}")
    ds = get_dataset(name)
    files = _registry_of(name, registry)
    report = progress or no_progress
    folder = data_root(root) / ds.name
    base = _base_url(ds, base_url)
    import pooch
    import requests

    store = pooch.create(path=folder, base_url=base, registry=dict(files), retry_if_failed=retries,
                         urls={f: base + quote(f) for f in files})
    downloader = pooch.HTTPDownloader(progressbar=False, timeout=TIMEOUT_S)
    actions: list[str] = []

    def record(path: str, action: str, _pooch: object) -> str:
        actions.append(action)
        return path

    label = f"fetching {ds.name}"
    report(label, 0, len(files))
    with _quiet_pooch(), _no_empty_folders_left(folder):
        for i, f in enumerate(files, 1):
            try:
                store.fetch(f, processor=record, downloader=downloader)
            except ValueError as exc:  # pooch: the hash of the download does not match
                raise DownloadError(f"dataset {ds.name}: {f} from {base + quote(f)} failed its SHA-256 check "
                                    f"(the server sent other bytes than those published); it was not "
                                    f"kept") from exc
            except requests.exceptions.HTTPError as exc:
                status = exc.response.status_code if exc.response is not None else "?"
                raise DownloadError(f"dataset {ds.name}: {f} could not be fetched from {base + quote(f)} "
                                    f"(HTTP {status})") from exc
            except requests.exceptions.RequestException as exc:
                raise DownloadError(f"dataset {ds.name}: {f} could not be fetched from {base + quote(f)} "
                                    f"({_reason(exc)}); for a machine without internet, copy the dataset "
                                    f"folder and set {DATA_DIR_ENV} to the folder that holds it") from exc
            report(label, i, len(files))
    downloaded = sum(a != "fetch" for a in actions)
    return FetchResult(path=folder, downloaded=downloaded, verified=len(files))


def _base_url(ds: Dataset, base_url: str | None) -> str:
    """The folder the dataset's files are fetched from, ending with ``/``."""
    mirror = base_url if base_url is not None else os.environ.get(DATA_URL_ENV, "")
    if not mirror:
        return ds.base_url
    if not isinstance(mirror, str) or not mirror.startswith(("http://", "https://")):
        raise ArgumentError(f"base_url must be an http:// or https:// address, not {mirror!r}")
    return mirror.rstrip("/") + f"/{quote(ds.name)}/"


def _reason(exc: BaseException) -> str:
    """A short reason for a failed request (requests' messages nest the whole urllib3 story)."""
    import requests

    if isinstance(exc, requests.exceptions.Timeout):
        return f"no answer within {TIMEOUT_S:.0f} s"
    if isinstance(exc, requests.exceptions.ConnectionError):
        return "the server is unreachable"
    return type(exc).__name__


@contextlib.contextmanager
def _no_empty_folders_left(folder: Path) -> Iterator[None]:
    """A fetch that fails removes the folders it made and left empty (files fetched before are kept)."""
    made = [p for p in (folder, *folder.parents) if not p.exists()]
    try:
        yield
    except BaseException:
        if folder.is_dir():
            for sub in sorted((p for p in folder.rglob("*") if p.is_dir()), key=lambda p: -len(p.parts)):
                with contextlib.suppress(OSError):
                    sub.rmdir()  # only an empty folder goes
        for p in made:
            with contextlib.suppress(OSError):
                p.rmdir()
        raise


@contextlib.contextmanager
def _quiet_pooch() -> Iterator[None]:
    """pooch logs each download to stderr through a handler of its own: the library never prints."""
    import pooch

    logger = pooch.get_logger()
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        logger.setLevel(level)


def _registry_of(name: str, registry: Mapping[str, str] | None) -> dict[str, str]:
    """``registry`` checked (paths and ``sha256:`` hashes), or the shipped registry of dataset ``name``."""
    if registry is None:
        return get_dataset(name).registry()
    if not isinstance(registry, Mapping) or not registry:
        raise ArgumentError("registry must map at least one file path to its 'sha256:<hex>' hash")
    out = {}
    for path, digest in registry.items():
        _check_entry(str(path), str(digest), "registry")
        out[str(path)] = str(digest)
    return out


def _check_entry(path: str, digest: str, where: str) -> None:
    parts = path.split("/")
    if not path or path.startswith("/") or any(p in ("", ".", "..") for p in parts) or any(c.isspace() for c in path):
        raise ArgumentError(f"{where}: file path {path!r} must be relative, without '..' or spaces")
    algo, _, hexdigest = digest.partition(":")
    if algo != "sha256" or len(hexdigest) != 64 or any(c not in "0123456789abcdef" for c in hexdigest):
        raise ArgumentError(f"{where}: hash of {path} must be 'sha256:' and 64 lower-case hex digits, "
                            f"not {digest!r}")


_REGISTRIES: dict[str, tuple[dict[str, str], int]] = {}


def _read_registry(name: str) -> tuple[dict[str, str], int]:
    """The shipped registry of ``name`` (pooch's format: ``path sha256:hex`` a line, ``#`` comments) and
    the total size its ``# bytes: N`` line records."""
    if name not in _REGISTRIES:
        text = resources.files(REGISTRY_PACKAGE).joinpath(f"{name}.txt").read_text(encoding="utf-8")
        files: dict[str, str] = {}
        size = 0
        for line in text.splitlines():
            line = line.strip()
            if line.startswith("# bytes:"):
                size = int(line.split(":", 1)[1])
            if not line or line.startswith("#"):
                continue
            path, digest = line.split()
            _check_entry(path, digest, f"registry {name}.txt")
            files[path] = digest
        _REGISTRIES[name] = (files, size)
    return _REGISTRIES[name]


def registry_text(name: str, folder: str | os.PathLike, exclude: tuple[str, ...] = ("SOURCE.md",)) -> str:
    """The registry of dataset ``name`` made from a complete copy in ``folder`` (every file but
    ``exclude``, sorted; a ``# bytes: N`` line with their total size). For ``tools/make_data_registry.py``."""
    import hashlib

    ds = get_dataset(name)
    base = Path(folder)
    if not base.is_dir():
        raise DatasetError(f"no folder {base} to make the registry of {ds.name} from")
    lines, size = [], 0
    for p in sorted(q for q in base.rglob("*") if q.is_file()):
        rel = p.relative_to(base).as_posix()
        if rel in exclude:
            continue
        digest = "sha256:" + hashlib.sha256(p.read_bytes()).hexdigest()
        _check_entry(rel, digest, str(base))
        lines.append(f"{rel} {digest}")
        size += p.stat().st_size
    if not lines:
        raise DatasetError(f"folder {base} holds no files of {ds.name}")
    head = [f"# {ds.name}: {ds.title} ({ds.homepage}), licence {ds.licence}",
            f"# files at {ds.base_url}<path>; written by tools/make_data_registry.py",
            f"# files: {len(lines)}", f"# bytes: {size}"]
    return "\n".join([*head, *lines]) + "\n"


def fetched_state(name: str, root: str | os.PathLike | None = None) -> str:
    """``"yes"`` (every file there), ``"partly"`` (some) or ``"no"`` (none), without hashing."""
    missing = len(missing_files(name, root))
    total = len(get_dataset(name).registry())
    return "yes" if missing == 0 else "no" if missing == total else "partly"
