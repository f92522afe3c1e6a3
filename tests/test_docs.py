"""The documentation cannot drift from the code (issue 47).

- The site builds with ``mkdocs build --strict`` (every warning an error: a broken link, a page missing
  from the nav, an API reference that no longer resolves).
- The generated reference pages (``docs/reference/commands.md`` from the typer app's ``--help``,
  ``docs/reference/scenario.md`` from the pydantic models and ``physynth.bounds.BOUNDS``) equal what
  ``tools/make_docs_reference.py`` writes now.
- Every ```` ```bash ```` and ```` ```python ```` block of the README and of the tutorials runs, in page
  order, in a scratch folder laid out like a clone (``docs/`` beside it, the real data at
  ``../shared/data``, ``PHYSYNTH_DATA_DIR`` pointing there). The convention (docs/index.md, "Examples that
  run") is an HTML comment on the line before a block:

  - ``<!-- docs-test: tiny "FIND" "REPLACE" ... -->``: the test replaces each FIND by its REPLACE (tiny
    sizes) before running the block, and fails if a FIND is not in the block;
  - ``<!-- docs-test: skip REASON -->``: the block is not run (set-up commands that install).

  Any other fence (```` ```text ````, ```` ```yaml ````) is not run.
- The notebook tutorial (``docs/tutorials/train-a-tracker-notebook.ipynb``) runs with nbclient in a process
  of its own, its cell tagged ``parameters`` replaced by tiny sizes; the site renders it as a page
  (mkdocs-jupyter, not executed there).
- The pages and the notebook run side by side, ``PHYSYNTH_DOCS_TEST_JOBS`` at a time (2 by default), each
  in its own scratch clone; nothing is skipped.
- Every ``tools/*.py``, ``benchmarks/*.py`` and ``docs/*.md`` path named in README.md and docs/ exists.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SHARED = ROOT.parent / "shared" / "data"
EXECUTED = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (DOCS / "tutorials").glob("*.md"))]
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```\s*$", re.M | re.S)
MARK = re.compile(r"^<!--\s*docs-test:\s*(\w+)([^\n]*?)-->$")  # one line, right above the fence


def blocks(page: Path) -> list[tuple[str, str, str | None, list[tuple[str, str]]]]:
    """(language, code, skip reason or None, substitutions) of every bash/python block of a page."""
    text = page.read_text(encoding="utf-8")
    found = []
    for m in FENCE.finditer(text):
        lang, code = m.group(1), m.group(2)
        if lang not in ("bash", "python"):
            continue
        before = text[: m.start()]
        mark = MARK.match(before.rstrip("\n").rsplit("\n", 1)[-1])
        skip, subs = None, []
        if mark is not None:
            kind, rest = mark.group(1), mark.group(2).strip()
            if kind == "skip":
                skip = rest or "no reason given"
            elif kind == "tiny":
                args = shlex.split(rest)
                assert args and len(args) % 2 == 0, f"{page.name}: tiny needs FIND REPLACE pairs: {rest!r}"
                subs = list(zip(args[::2], args[1::2], strict=True))
            else:
                raise AssertionError(f"{page.name}: unknown docs-test marker {kind!r}")
        found.append((lang, code, skip, subs))
    return found


def tiny(code: str, subs: list[tuple[str, str]], where: str) -> str:
    for find, repl in subs:
        assert find in code, f"{where}: the tiny substitution {find!r} is not in its block (the page changed?)"
        code = code.replace(find, repl)
    return code


def scratch(tmp_path: Path) -> tuple[Path, dict[str, str]]:
    """A folder laid out like a clone: docs/ in it, ../shared/data beside it; the venv's commands on PATH."""
    work = tmp_path / "clone"
    work.mkdir()
    (work / "docs").symlink_to(DOCS)
    if SHARED.is_dir():
        (tmp_path / "shared").mkdir()
        (tmp_path / "shared" / "data").symlink_to(SHARED)
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
           "PHYSYNTH_DATA_DIR": str(SHARED), "MPLBACKEND": "Agg", "PYTHONHASHSEED": "0",
           # one thread per process, as the command line runs (docs/scale.md, "BLAS threads"): the notebook and
           # the Python blocks use the API, which leaves the environment alone, and threads only spin here
           "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    env.pop("PHYSYNTH_SHARED_DATA", None)
    return work, env


def test_marker_parsing_finds_skips_and_substitutions(tmp_path):
    page = tmp_path / "p.md"
    page.write_text("x\n<!-- docs-test: tiny \"-n 50\" \"-n 2\" -->\n```bash\nphysynth generate -n 50\n```\n\n"
                    "<!-- docs-test: skip installs -->\n```bash\nmake run\n```\n```text\nnot run\n```\n"
                    "```python\nprint(1)\n```\n", encoding="utf-8")
    got = blocks(page)
    assert [(lang, skip, subs) for lang, _, skip, subs in got] == [
        ("bash", None, [("-n 50", "-n 2")]), ("bash", "installs", []), ("python", None, [])]
    assert tiny(got[0][1], got[0][3], "p") == "physynth generate -n 2\n"
    with pytest.raises(AssertionError, match="not in its block"):
        tiny("physynth generate -n 20\n", [("-n 50", "-n 2")], "p")


def uses_real_data(page: str) -> bool:
    text = (ROOT / page).read_text(encoding="utf-8")
    return "physynth data" in text or "../shared/data" in text


def run_page(page: str, tmp: Path) -> str | None:
    """Run every runnable block of a page in order in its own scratch clone; the failure, or None."""
    work, env = scratch(tmp)
    for k, (lang, code, skip, subs) in enumerate(blocks(ROOT / page)):
        if skip is not None:
            continue
        where = f"{page}, block {k + 1}"
        code = tiny(code, subs, where)
        if lang == "bash":
            cmd = ["bash", "-euo", "pipefail", "-c", code]
        else:
            script = tmp / f"block{k + 1}.py"
            script.write_text(code, encoding="utf-8")
            cmd = [sys.executable, str(script)]
        proc = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=300)
        if proc.returncode != 0:
            return f"{where} failed:\n{code}\n--- stderr:\n{proc.stderr[-3000:]}"
    return None


NOTEBOOK = DOCS / "tutorials" / "train-a-tracker-notebook.ipynb"
NOTEBOOK_TINY = [("PRETRAIN_TRACES = 64", "PRETRAIN_TRACES = 2"), ("PRETRAIN_EPOCHS = 5", "PRETRAIN_EPOCHS = 1"),
                 ("FINETUNE_EPOCHS = 20", "FINETUNE_EPOCHS = 1"), ("WINDOWS_PER_TRACE = 32", "WINDOWS_PER_TRACE = 2")]
# executes a notebook in a process of its own (its environment the scratch clone's), writes it with outputs
NOTEBOOK_RUNNER = """
import sys
import nbclient
import nbformat
nb = nbformat.read(sys.argv[1], as_version=4)
nbclient.NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": sys.argv[2]}}).execute()
nbformat.write(nb, sys.argv[3])
"""


def run_notebook(tmp: Path) -> str:
    """The notebook tutorial run with its ``parameters`` cell made tiny; the text of its outputs."""
    import nbformat

    nb = nbformat.read(NOTEBOOK, as_version=4)
    params = [c for c in nb.cells if "parameters" in c.get("metadata", {}).get("tags", [])]
    assert len(params) == 1, "the notebook needs one cell tagged 'parameters'"
    params[0].source = tiny(params[0].source, NOTEBOOK_TINY, "notebook")
    work, env = scratch(tmp)
    nbformat.write(nb, tmp / "in.ipynb")
    cmd = [sys.executable, "-c", NOTEBOOK_RUNNER, str(tmp / "in.ipynb"), str(work), str(tmp / "out.ipynb")]
    proc = subprocess.run(cmd, cwd=work, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"the notebook failed:\n{proc.stderr[-4000:]}"
    out = nbformat.read(tmp / "out.ipynb", as_version=4)
    return "".join(o.get("text", "") for c in out.cells if c.cell_type == "code" for o in c.get("outputs", []))


def notebook_runs_here() -> str | None:
    """Why the notebook cannot run here, or None."""
    for mod in ("nbformat", "nbclient", "ipykernel"):
        try:
            __import__(mod)
        except ImportError:
            return f"{mod} is not installed"
    if not SHARED.is_dir():
        return f"the notebook scores on a real run, and {SHARED} is absent"
    return None


# The pages and the notebook are independent (each in a scratch clone of its own), so they run side by side,
# PHYSYNTH_DOCS_TEST_JOBS at a time (2 by default; 1 runs them one after the other), longest first; every
# block still runs, in page order. Each test below waits for its own page.
JOBS = max(1, int(os.environ.get("PHYSYNTH_DOCS_TEST_JOBS", "2")))
LONGEST_FIRST = ["README.md", "docs/tutorials/calibrate-your-site.md", "notebook"]


@pytest.fixture(scope="module")
def executed(request, tmp_path_factory):
    from concurrent.futures import ThreadPoolExecutor

    selected = set()  # only what the tests selected in this session wait for (pytest -k ...)
    for item in request.session.items:
        if item.module is request.module and "executed" in getattr(item, "fixturenames", ()):
            callspec = getattr(item, "callspec", None)
            selected.add(callspec.params["page"] if callspec is not None else "notebook")
    jobs = [j for j in LONGEST_FIRST if j in selected]
    jobs += [p for p in EXECUTED if p in selected and p not in jobs]
    pool = ThreadPoolExecutor(max_workers=JOBS)
    futures = {}
    for job in jobs:
        tmp = tmp_path_factory.mktemp(re.sub(r"\W+", "-", job))
        if job == "notebook":
            if notebook_runs_here() is None:
                futures[job] = pool.submit(run_notebook, tmp)
        elif not (uses_real_data(job) and not SHARED.is_dir()):
            futures[job] = pool.submit(run_page, job, tmp)
    yield futures
    for f in futures.values():
        f.cancel()
    pool.shutdown(wait=True)


@pytest.mark.parametrize("page", EXECUTED)
def test_page_examples_run(page, executed):
    found = blocks(ROOT / page)
    assert any(skip is None for _, _, skip, _ in found), f"{page}: no runnable example"
    if uses_real_data(page) and not SHARED.is_dir():
        pytest.skip(f"{page} uses the real data, and {SHARED} is absent")
    failure = executed[page].result()
    assert failure is None, failure


def test_generated_reference_pages_are_current():
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "make_docs_reference.py"), "--check"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def test_reference_pages_name_every_command_and_bounded_field():
    from physynth.bounds import BOUNDS

    commands = (DOCS / "reference" / "commands.md").read_text(encoding="utf-8")
    for name in ("generate", "calibrate", "validate", "import hanyang", "study tracking", "data fetch"):
        assert f"## `physynth {name}`" in commands, name
    assert "--vary-site" in commands and "--crop-to-uwb" in commands
    scenario = (DOCS / "reference" / "scenario.md").read_text(encoding="utf-8")
    rows = set(re.findall(r"^\| `([^`]+)` \|", scenario, re.M))
    covered = {k for k in BOUNDS if re.sub(r"(\[\])+$", "", k) in rows}
    assert not set(BOUNDS) - covered, sorted(set(BOUNDS) - covered)[:10]


def test_site_builds_strict(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    pytest.importorskip("mkdocs_jupyter")
    mkdocs = Path(sys.executable).parent / "mkdocs"
    cmd = [str(mkdocs)] if mkdocs.exists() else [sys.executable, "-m", "mkdocs"]
    proc = subprocess.run([*cmd, "build", "--strict", "--site-dir", str(tmp_path / "site")], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (tmp_path / "site" / "index.html").exists()
    assert (tmp_path / "site" / "reference" / "api" / "index.html").exists()
    api = (tmp_path / "site" / "reference" / "api" / "index.html").read_text(encoding="utf-8")
    assert "generate_traces" in api and "load_scenario" in api
    assert (tmp_path / "site" / "img" / "hanyang-case2-transfer-residuals.png").exists()
    notebook = tmp_path / "site" / "tutorials" / "train-a-tracker-notebook" / "index.html"
    assert notebook.exists() and "SyntheticWindows" in notebook.read_text(encoding="utf-8")


def test_no_page_and_notebook_share_a_url():
    """tutorials/x.md and tutorials/x.ipynb would both be tutorials/x/ on the site, one silently lost."""
    stems = [p.with_suffix("") for p in [*DOCS.rglob("*.md"), *DOCS.rglob("*.ipynb")]]
    assert len(stems) == len(set(stems)), sorted({str(s) for s in stems if stems.count(s) > 1})


def test_every_page_is_in_the_nav():
    import yaml

    nav = json.dumps(yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))["nav"])
    pages = sorted(str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md"))
    assert pages and not [p for p in pages if f'"{p}"' not in nav]


def test_notebook_tutorial_runs(executed):
    why = notebook_runs_here()
    if why is not None:
        pytest.skip(why)
    out = executed["notebook"].result()
    assert "RMSE" in out, out[-2000:]


PATH_REF = re.compile(r"(?<![\w/.-])((?:tools|benchmarks)/[\w.-]+\.py|docs/[\w./-]+\.md)\b")
REMOVED_HEADING = "## 2026-12-05: investigations removed from tools/"


def named_paths(text: str) -> set[str]:
    """Every ``tools/*.py``, ``benchmarks/*.py`` and ``docs/*.md`` path a page names, in prose or code."""
    return set(PATH_REF.findall(text))


def test_named_paths_parser():
    text = "run `python tools/loo_hanyang.py --n 50`, see docs/imu.md and benchmarks/bench_cli.py; not src/tools/x.py"
    assert named_paths(text) == {"tools/loo_hanyang.py", "docs/imu.md", "benchmarks/bench_cli.py"}


def test_every_named_tool_benchmark_and_page_exists():
    """A script or page named in README.md or docs/ exists; the experiments log may name a removed
    investigation only in its table of investigations removed from tools/ (``git show`` reads them)."""
    log = DOCS / "experiments.md"
    removed = log.read_text(encoding="utf-8").split(REMOVED_HEADING, 1)
    assert len(removed) == 2, f"docs/experiments.md has no section {REMOVED_HEADING!r}"
    removed_names = set(re.findall(r"^\| `([\w.-]+\.py)` \|", removed[1].split("\n## ", 1)[0], re.M))
    missing = []
    for page in [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]:
        for ref in sorted(named_paths(page.read_text(encoding="utf-8"))):
            if (ROOT / ref).exists():
                continue
            if page == log and ref.startswith("tools/") and Path(ref).name in removed_names:
                continue
            missing.append(f"{page.relative_to(ROOT)}: {ref}")
    assert not missing, "named but absent:\n" + "\n".join(missing)
