"""zstd settings for the chunks of ROS 2 bags (MCAP), side by side in one run on the same records.

    python benchmarks/bench_bag_zstd.py [-n N] [--repeat R]

Generates ``N`` traces of the default scenario twice (the ENU IMU alone, as by default, and with the
body-frame IMU), builds every chunk's message records as the export does (record heads included,
``physynth.io.export.mcap._chunk`` without compression) and compresses them, one thread, with each setting:
zstd level 1 as ROS 2 writes it, level 1 with the match finder the export uses (``mcap.ZSTD_HASH_LOG``,
``mcap.ZSTD_MIN_MATCH``), and the faster levels of ROS 2's ``zstd_fast`` preset (-5) and -3. Prints the
best CPU time per trace over ``R`` repetitions and the compressed bytes per trace.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from physynth.io.dataset import iter_traces
from physynth.io.export import mcap
from physynth.io.export.rosbag2 import _typestore, trace_topics
from physynth.io.scenario_file import load_scenario
from physynth.workflows import generate_dataset


def chunks_of_trace(trace: Any) -> list[bytes]:
    """Every chunk's uncompressed records of the bag of one trace (as the export builds them)."""
    out = []
    for cid, topic in enumerate(trace_topics(_typestore(), trace, {}), 1):
        n, width = topic.messages.n, topic.messages.size
        step = max(1, mcap.CHUNK_BYTES // width)
        for a in range(0, n, step):
            b = min(a + step, n)
            rows = np.empty((b - a, width), dtype=np.uint8)
            pieces, _ = mcap._chunk(topic.messages, rows, a, b, cid, topic.stamps[a:b], "")  # uncompressed:
            out.append(bytes(pieces[1]))  # the chunk's records
    return out


def chunks_of(path: Path) -> list[bytes]:
    """Every chunk's uncompressed records of the bags of the dataset at ``path``."""
    return [c for trace in iter_traces(path) for c in chunks_of_trace(trace)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("-n", type=int, default=4)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    zstd = mcap._zstd()
    opt = zstd.CompressionParameter
    settings = {
        "level 1 (ROS 2)": {opt.compression_level: 1},
        f"level 1, hash_log {mcap.ZSTD_HASH_LOG}, min_match {mcap.ZSTD_MIN_MATCH} (export)": {
            opt.compression_level: 1, opt.hash_log: mcap.ZSTD_HASH_LOG, opt.min_match: mcap.ZSTD_MIN_MATCH},
        "level -3": {opt.compression_level: -3},
        "level -5 (ROS 2 zstd_fast)": {opt.compression_level: -5},
    }
    tmp = Path(tempfile.mkdtemp(prefix="bench-zstd-"))
    try:
        for frames in (["enu-gravity-free"], ["enu-gravity-free", "body-flu"]):
            scn = load_scenario("cablecar-descending").model_copy(update={"imu_frames": frames})
            path, _ = generate_dataset(scn, args.n, tmp / "-".join(frames), seed=1)
            chunks = chunks_of(path)
            raw = sum(map(len, chunks))
            print(f"IMU frames {', '.join(frames)}: {args.n} traces, {raw / args.n / 1e6:.1f} MB of records per trace")
            for name, options in settings.items():
                best = float("inf")
                for _ in range(args.repeat):
                    c0 = time.process_time()
                    packed = sum(len(zstd.compress(c, options=options)) for c in chunks)
                    best = min(best, time.process_time() - c0)
                print(f"  {name:52s} {1e3 * best / args.n:6.2f} ms CPU per trace  {packed / args.n / 1e6:5.2f} MB")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
