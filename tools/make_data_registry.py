"""Write the registries of the fetchable datasets (src/physynth/data_registry/<name>.txt) from a local copy.

    .venv/bin/python tools/make_data_registry.py [--data ../shared/data] [--out src/physynth/data_registry]
                                                 [--check]

The copy must be byte-identical to the upstream commit that physynth.data names for each dataset (every
file but SOURCE.md, which this project wrote): each line is ``<path> sha256:<hex>``, in pooch's registry
format, with a ``# bytes: N`` line giving the total size. ``--check`` writes nothing and exits 1 when a
shipped registry differs from what the copy gives.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from physynth.data import list_datasets, registry_text  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data",
                    help="folder holding one folder per dataset (default: ../shared/data beside the clone)")
    ap.add_argument("--out", type=Path, default=ROOT / "src" / "physynth" / "data_registry",
                    help="where the registries go (default: the package's data_registry)")
    ap.add_argument("--check", action="store_true", help="compare with the shipped registries, write nothing")
    args = ap.parse_args(argv)
    differ = 0
    for ds in list_datasets():
        text = registry_text(ds.name, args.data / ds.name)
        target = args.out / f"{ds.name}.txt"
        n = sum(1 for line in text.splitlines() if line and not line.startswith("#"))
        if args.check:
            same = target.is_file() and target.read_text(encoding="utf-8") == text
            differ += not same
            print(f"{ds.name}: {n} files, {'same as' if same else 'DIFFERS from'} {target}")
            continue
        args.out.mkdir(parents=True, exist_ok=True)
        tmp = target.with_suffix(".tmp")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(target)
        print(f"{ds.name}: {n} files -> {target}")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
