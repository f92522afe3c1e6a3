"""Write src/physynth/io/export/ros2_types.json: the message definition and RIHS01 type hash of every
message type the ROS 2 bag export writes, as ``rosbags`` makes them for ROS 2 Humble.

    python tools/ros2_types.py [--check]

The export reads them from that file (making them takes ``rosbags`` about 0.1 s per process, a tenth of
a 20-trace export); ``tests/test_export_rosbag2.py`` makes them again and fails when they differ.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from physynth.io.export.rosbag2 import MESSAGE_TYPES, _type_info_of

OUT = Path(__file__).resolve().parents[1] / "src" / "physynth" / "io" / "export" / "ros2_types.json"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true",
                    help="compare with the file instead of writing it (exit 1 if they differ)")
    args = ap.parse_args()
    table = {t: dict(zip(("msgdef", "rihs01"), _type_info_of(t), strict=True)) for t in MESSAGE_TYPES}
    text = json.dumps(table, indent=1, sort_keys=True) + "\n"
    if args.check:
        same = OUT.is_file() and OUT.read_text(encoding="utf-8") == text
        print(f"{OUT}: {'up to date' if same else 'differs from what rosbags makes'}")
        sys.exit(0 if same else 1)
    OUT.write_text(text, encoding="utf-8")
    print(f"wrote {OUT} ({len(table)} message types)")


if __name__ == "__main__":
    main()
