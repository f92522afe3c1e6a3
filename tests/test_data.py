"""``physynth.data`` and ``physynth data``: fetching the real datasets over HTTP, checked by SHA-256.

A real HTTP server (``http.server`` in a thread) serves a mirror made of a few files of ``../shared/data``
(byte-identical to the upstream repositories), laid out as upstream under one folder per dataset; the
fetch goes through pooch and requests as it would from GitHub. Skipped only when ``../shared/data`` is
absent.
"""

from __future__ import annotations

import functools
import shutil
import socket
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from test_cli import run  # physynth.cli.main in process: (exit code, stdout, stderr)

from physynth import data
from physynth.errors import ArgumentError, DatasetError

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
pytestmark = pytest.mark.skipif(not SHARED.is_dir(), reason=f"shared real data not found at {SHARED}")

FEW = {"broad-imu": ("LICENSE", "README.md", "data_mat/trials.json"),
       "hanyang-uwb": ("LICENSE", "Dynamic_measurements/LOS/Trajectory_A/Case_1/RMSD_results.txt")}


def subset(name: str) -> dict[str, str]:
    """A few files of the shipped registry (their hashes are the shipped ones)."""
    reg = data.get_dataset(name).registry()
    return {f: reg[f] for f in FEW[name]}


class Mirror:
    """A folder laid out like a data root, served over HTTP on localhost; ``requests`` lists the paths asked."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.requests: list[str] = []
        mirror = self

        class Handler(SimpleHTTPRequestHandler):
            def log_message(self, *args: object) -> None:
                mirror.requests.append(self.path)

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Handler, directory=str(folder)))
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.thread = threading.Thread(target=self.server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)

    def add(self, name: str, rel: str) -> Path:
        target = self.folder / name / rel
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(SHARED / name / rel, target)
        return target


@pytest.fixture
def mirror(tmp_path, monkeypatch):
    for var in (data.DATA_DIR_ENV, data.DATA_URL_ENV, "PHYSYNTH_SHARED_DATA"):
        monkeypatch.delenv(var, raising=False)
    m = Mirror(tmp_path / "mirror")
    for name, files in FEW.items():
        for rel in files:
            m.add(name, rel)
    m.thread.start()
    yield m
    m.server.shutdown()
    m.server.server_close()


def dead_url() -> str:
    """An address where nothing listens (connection refused): no network."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    return f"http://127.0.0.1:{port}"


def test_shipped_registry_covers_every_shared_file():
    """The registries name every file of the shared copy (but SOURCE.md, ours) with its SHA-256."""
    for ds in data.list_datasets():
        shipped = (Path(data.__file__).parent / "data_registry" / f"{ds.name}.txt").read_text(encoding="utf-8")
        assert data.registry_text(ds.name, SHARED / ds.name) == shipped
        files = {p.relative_to(SHARED / ds.name).as_posix() for p in (SHARED / ds.name).rglob("*") if p.is_file()}
        assert set(ds.registry()) == files - {"SOURCE.md"}
        assert ds.size_bytes == sum((SHARED / ds.name / f).stat().st_size for f in ds.registry())
        assert ds.base_url.startswith("https://raw.githubusercontent.com/") and len(ds.base_url.split("/")[5]) == 40


def test_fetch_over_http_into_an_empty_root(mirror, tmp_path):
    calls = []
    result = data.fetch("broad-imu", root=tmp_path / "root", base_url=mirror.url, registry=subset("broad-imu"),
                        progress=lambda m, d=None, t=None: calls.append((m, d, t)))
    assert result.path == tmp_path / "root" / "broad-imu"
    assert (result.downloaded, result.verified) == (3, 3)
    for rel in FEW["broad-imu"]:
        assert (result.path / rel).read_bytes() == (SHARED / "broad-imu" / rel).read_bytes()
    assert sorted(p.name for p in result.path.rglob("*") if p.is_file()) == ["LICENSE", "README.md", "trials.json"]
    assert calls[0] == ("fetching broad-imu", 0, 3) and calls[-1] == ("fetching broad-imu", 3, 3)
    assert sorted(mirror.requests) == sorted(f"/broad-imu/{rel}" for rel in FEW["broad-imu"])
    assert data.dataset_path("broad-imu", tmp_path / "root", registry=subset("broad-imu")) == result.path

    mirror.requests.clear()  # a second fetch finds every file good: nothing is asked of the server
    again = data.fetch("broad-imu", root=tmp_path / "root", base_url=mirror.url, registry=subset("broad-imu"))
    assert (again.downloaded, again.verified) == (0, 3) and mirror.requests == []


def test_environment_sets_root_and_mirror(mirror, tmp_path, monkeypatch):
    monkeypatch.setenv(data.DATA_DIR_ENV, str(tmp_path / "env-root"))
    monkeypatch.setenv(data.DATA_URL_ENV, mirror.url + "/")
    assert data.data_root() == tmp_path / "env-root"
    assert data.data_root(tmp_path / "arg") == tmp_path / "arg"  # an explicit root wins
    result = data.fetch("hanyang-uwb", registry=subset("hanyang-uwb"))
    assert result.path == tmp_path / "env-root" / "hanyang-uwb" and result.downloaded == 2
    assert mirror.requests[0].startswith("/hanyang-uwb/")


def test_corrupted_download_is_refused_and_not_kept(mirror, tmp_path):
    served = mirror.folder / "broad-imu" / "data_mat" / "trials.json"
    served.write_bytes(served.read_bytes().replace(b"1", b"2", 1))  # one byte changed on the server
    root = tmp_path / "root"
    with pytest.raises(data.DownloadError, match=r"^dataset broad-imu: data_mat/trials.json from http://.* "
                                                 r"failed its SHA-256 check"):
        data.fetch("broad-imu", root=root, base_url=mirror.url, registry=subset("broad-imu"))
    left = sorted(p.relative_to(root).as_posix() for p in root.rglob("*"))
    assert left == ["broad-imu", "broad-imu/LICENSE", "broad-imu/README.md"]  # no trials.json, no temporary file
    with pytest.raises(DatasetError, match=r"dataset broad-imu is incomplete .* 1 of 3 files missing "
                                           r"\(first: data_mat/trials.json\)"):
        data.dataset_path("broad-imu", root, registry=subset("broad-imu"))


def test_damaged_local_file_is_fetched_again(mirror, tmp_path):
    root = tmp_path / "root"
    data.fetch("broad-imu", root=root, base_url=mirror.url, registry=subset("broad-imu"))
    (root / "broad-imu" / "README.md").write_text("damaged", encoding="utf-8")
    result = data.fetch("broad-imu", root=root, base_url=mirror.url, registry=subset("broad-imu"))
    assert result.downloaded == 1
    assert (root / "broad-imu" / "README.md").read_bytes() == (SHARED / "broad-imu" / "README.md").read_bytes()


def test_missing_file_on_server_and_no_server(mirror, tmp_path):
    (mirror.folder / "broad-imu" / "LICENSE").unlink()
    with pytest.raises(data.DownloadError, match=r"LICENSE could not be fetched from http://.*/broad-imu/LICENSE "
                                                 r"\(HTTP 404\)"):
        data.fetch("broad-imu", root=tmp_path / "a", base_url=mirror.url, registry=subset("broad-imu"), retries=0)
    with pytest.raises(data.DownloadError, match=r"\(the server is unreachable\).*PHYSYNTH_DATA_DIR"):
        data.fetch("broad-imu", root=tmp_path / "b" / "c", base_url=dead_url(), registry=subset("broad-imu"),
                   retries=0)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()  # no empty folders left behind


def test_bad_arguments(tmp_path):
    with pytest.raises(ArgumentError, match=r"unknown dataset 'nope'; known: hanyang-uwb, broad-imu"):
        data.fetch("nope", root=tmp_path)
    with pytest.raises(ArgumentError, match="retries must be a whole number"):
        data.fetch("broad-imu", root=tmp_path, retries=-1)
    with pytest.raises(ArgumentError, match="base_url must be an http"):
        data.fetch("broad-imu", root=tmp_path, base_url="file:///tmp")
    with pytest.raises(ArgumentError, match=r"file path '../x' must be relative"):
        data.fetch("broad-imu", root=tmp_path, registry={"../x": "sha256:" + "0" * 64})
    with pytest.raises(ArgumentError, match=r"hash of LICENSE must be 'sha256:'"):
        data.fetch("broad-imu", root=tmp_path, registry={"LICENSE": "md5:abc"})
    with pytest.raises(DatasetError, match=r"^dataset hanyang-uwb is not fetched \(no folder .*\): fetch it with "
                                           r"physynth.data.fetch\('hanyang-uwb'\)"):
        data.dataset_path("hanyang-uwb", tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_local_copy_serves_without_network(tmp_path, monkeypatch):
    """A folder holding a copy is a data root as it is: fetch only checks the hashes, path finds it."""
    monkeypatch.setenv(data.DATA_URL_ENV, dead_url())
    root = tmp_path / "copy"
    shutil.copytree(SHARED / "broad-imu", root / "broad-imu")
    result = data.fetch("broad-imu", root=root)
    assert (result.downloaded, result.verified) == (0, 7)
    assert data.dataset_path("broad-imu", root) == root / "broad-imu"
    assert data.fetched_state("broad-imu", root) == "yes" and data.fetched_state("hanyang-uwb", root) == "no"
    assert data.dataset_path("hanyang-uwb", SHARED) == SHARED / "hanyang-uwb"


# ------------------------------------------------------------------------------------------------------
# the command line
# ------------------------------------------------------------------------------------------------------


def test_cli_list_and_path_on_the_shared_copy(capsys, monkeypatch):
    monkeypatch.delenv(data.DATA_DIR_ENV, raising=False)
    code, out, err = run(capsys, "data", "list", "--data-root", SHARED)
    assert code == 0 and err == ""
    lines = out.splitlines()
    assert lines[0].split() == ["dataset", "fetched", "size", "licence", "what"]
    assert lines[1].split()[:5] == ["hanyang-uwb", "yes", "19.5", "MB", "Apache-2.0"]
    assert lines[2].split()[:5] == ["broad-imu", "yes", "15.1", "MB", "CC-BY-4.0"]
    assert lines[-1] == f"data root: {SHARED}"
    code, out, _ = run(capsys, "data", "path", "hanyang-uwb", "--data-root", SHARED)
    assert code == 0 and out == f"{SHARED / 'hanyang-uwb'}\n"


@pytest.mark.parametrize(("args", "needle"), [
    (["data", "fetch", "nope"], "unknown dataset 'nope'"),
    (["data", "path", "nope"], "unknown dataset 'nope'"),
    (["data", "fetch", "broad-imu", "--base-url", "ftp://x"], "--base-url must be an http"),
    (["data", "path", "broad-imu", "--data-root", "{tmp}"], "is not fetched (no folder"),
    (["data", "fetch"], "Missing argument"),
])
def test_cli_bad_input_exit_2_one_line(capsys, tmp_path, args, needle):
    code, out, err = run(capsys, *[a.format(tmp=tmp_path) for a in args])
    assert code == 2 and out == "" and err.count("\n") == 1 and needle in err, err
    assert err.startswith("physynth: error: ")
    if "not fetched" in err:
        assert "fetch it with physynth data fetch broad-imu" in err  # the command, not the Python call


def test_cli_fetch_local_copy_and_failed_download(capsys, tmp_path, mirror):
    root = tmp_path / "copy"
    shutil.copytree(SHARED / "broad-imu", root / "broad-imu")
    code, out, err = run(capsys, "data", "fetch", "broad-imu", "--data-root", root, "--base-url", dead_url())
    assert code == 0 and err == ""
    assert out.splitlines()[0] == f"broad-imu: 7 files verified (nothing to download) in {root / 'broad-imu'}"
    assert "cite: D. Laidig" in out and "doi:10.3390/data6070072" in out
    # the mirror holds 3 of the 7 files: the 4th (alphabetically) is a 404, one line, exit 1
    code, out, err = run(capsys, "data", "fetch", "broad-imu", "--data-root", tmp_path / "new", "--base-url",
                         mirror.url, "-q")
    assert code == 1 and out == "" and err.count("\n") == 1
    assert err.startswith("physynth: error: dataset broad-imu: data_mat/10_undisturbed_slow_translation_A.mat "
                          "could not be fetched") and "(HTTP 404)" in err
    assert sorted(p.name for p in (tmp_path / "new" / "broad-imu").rglob("*") if p.is_file()) == ["LICENSE",
                                                                                                   "README.md"]


def test_tracking_default_runs_say_to_fetch(tmp_path, monkeypatch, capsys):
    from physynth.errors import PhySynthError
    from physynth.studies.tracking import default_data_root, hanyang_default_runs

    monkeypatch.delenv("PHYSYNTH_SHARED_DATA", raising=False)
    monkeypatch.setenv(data.DATA_DIR_ENV, str(tmp_path))
    assert default_data_root() == tmp_path
    with pytest.raises(PhySynthError, match=r"dataset hanyang-uwb is not fetched"):
        hanyang_default_runs()
    code, _, err = run(capsys, "study", "tracking", "--out", tmp_path / "study")  # the command says it in its words
    assert code == 2 and "fetch them with physynth data fetch hanyang-uwb" in err
    shutil.copytree(SHARED / "hanyang-uwb" / "Dynamic_measurements" / "LOS", tmp_path / "hanyang-uwb" /
                    "Dynamic_measurements" / "LOS")  # half of the runs: the missing files are counted
    with pytest.raises(PhySynthError, match=r"of their \d+ files are missing \(first: Dynamic_measurements/NLOS/"):
        hanyang_default_runs()
    monkeypatch.delenv(data.DATA_DIR_ENV)
    assert default_data_root() == SHARED  # a clone with ../shared/data beside it
