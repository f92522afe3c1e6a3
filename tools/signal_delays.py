"""Send a signal to a real ``physynth`` command at a spread of delays and tabulate what happened.

The command runs in its own process group and the signal goes to the whole group, as a terminal's
Ctrl-C does. For each delay: the exit code, the seconds from the signal to the exit, the lines on
stderr (and whether any is a traceback or a library's log), whether the output exists, and any of the
command's processes left running (issue 44; docs/reliability.md).

    python tools/signal_delays.py --signal INT --delays 0.5,1,2,3,4,6 -- \
        generate --scenario cablecar-descending -n 3000 --seed 4 --out {out}
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _descendants(pid: int) -> list[int]:
    """Every process whose ancestry leads to ``pid`` (from /proc), or in its session."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if fields[0] != "Z" and (int(fields[3]) == pid or int(fields[1]) == pid):  # a zombie has ended
            found.append(int(d.name))
    return found


def one(args: list[str], sig: int, delay: float, work: Path) -> dict:
    out = work / f"o{time.monotonic_ns()}"
    argv = [a.replace("{out}", str(out)) for a in args]
    err_path = work / "stderr.txt"
    with open(err_path, "w") as err:
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "physynth.cli", *argv], stdout=subprocess.DEVNULL,
                                stderr=err, cwd=work, start_new_session=True)
        while proc.poll() is None and time.monotonic() < t0 + delay:
            time.sleep(0.01)
        sent = time.monotonic()
        if proc.poll() is None:
            os.killpg(proc.pid, sig)
        try:
            proc.wait(timeout=300)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        t1 = time.monotonic()
    time.sleep(0.5)
    left = _descendants(proc.pid)
    names = []
    for p in left:
        try:
            names.append(Path(f"/proc/{p}/cmdline").read_bytes().replace(b"\0", b" ").decode()[:120])
        except OSError:
            pass
    for p in left:
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass
    lines = err_path.read_text().splitlines()
    tmp = [p for p in work.rglob("*.tmp-*") if out.name in str(p)]
    complete = (out / "dataset.json").exists() or out.is_file()
    for p in work.glob(f".{out.name}*"):
        shutil.rmtree(p, ignore_errors=True)
    shutil.rmtree(out, ignore_errors=True)
    noisy = [ln for ln in lines if not ln.startswith(("physynth:", "  - ")) and ln.strip()]
    return {"delay": delay, "exit": proc.returncode, "after_s": round(t1 - sent, 1), "total_s": round(t1 - t0, 1),
            "lines": len(lines), "foreign": len(noisy), "traceback": any("Traceback" in ln for ln in lines),
            "output": complete, "left": len(left), "tmp": len(tmp), "left_names": names,
            "last": lines[-1][:100] if lines else ""}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--signal", default="INT", help="INT, TERM or HUP")
    ap.add_argument("--delays", default="0.5,1,1.5,2,2.5,3,3.5,4,5,6")
    ap.add_argument("command", nargs=argparse.REMAINDER)
    a = ap.parse_args()
    cmd = [c for c in a.command if c != "--"]
    sig = getattr(signal, "SIG" + a.signal)
    print("| delay s | exit | run s | exit after s | stderr lines | foreign lines | traceback | output "
          "| temp files left | processes left |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for d in (float(x) for x in a.delays.split(",")):
            r = one(cmd, sig, d, Path(tmp))
            print(f"| {d:g} | {r['exit']} | {r['total_s']} | {r['after_s']} | {r['lines']} | {r['foreign']} | "
                  f"{'yes' if r['traceback'] else 'no'} | {'yes' if r['output'] else 'no'} | {r['tmp']} | "
                  f"{r['left']} |", flush=True)
            for n in r["left_names"]:
                print(f"<!-- left running: {n} -->", file=sys.stderr)


if __name__ == "__main__":
    main()
