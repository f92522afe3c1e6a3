"""Does a per-anchor outage with a minimum length, or an Erlang one, fit the Hanyang runs better?

    .venv/bin/python tools/outage_shape_check.py [--data ../shared/data/hanyang-uwb] [--max-k 4]

The calibration's per-anchor availability is a two-state chain per attempt (up with independent
dropouts, outage with geometric length: :func:`physynth.calibrate.availability_fit.fit_dropout_outage`).
The pooled missed-burst runs of the four shared runs have few runs of two misses and a bump at three,
which suggests a minimum outage. This tool fits, per anchor over the four runs pooled, by maximum
likelihood on the same run-length statistics (internal, leading, trailing and whole-block runs of
misses), two larger chains with the same three parameters (onset, exit, dropout) and an integer k:

- ``min k``: an outage lasts at least k attempts (k - 1 deterministic states, then the geometric one);
- ``Erlang k``: an outage passes k geometric phases of the same exit probability.

k = 1 is the calibration's chain in both families: its log-likelihood is printed next to the
calibration's own (they agree), so a better k would show as a higher log-likelihood.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.special import expit, logit

from physynth.calibrate import availability_fit as af
from physynth.io.importers import import_hanyang

RUNS = ("LOS/Trajectory_A/Case_1", "LOS/Trajectory_A/Case_2", "NLOS/Trajectory_A/Case_1", "NLOS/Trajectory_A/Case_2")
DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "hanyang-uwb"
N_EXACT = 256
"""Run lengths up to this are summed exactly; longer ones extrapolated with the dominant eigenvalue."""


def chain(alpha: float, beta: float, pd: float, k: int, family: str) -> tuple[np.ndarray, ...]:
    """(A, Dm, dh, pi) of the chain: state 0 up, states 1..k the outage's."""
    s = k + 1
    a = np.zeros((s, s))
    a[0, 0], a[0, 1] = 1.0 - alpha, alpha
    for i in range(1, s):
        if family == "min" and i < k:
            a[i, i + 1] = 1.0  # the minimum: one attempt per state, no exit
        else:
            a[i, i] = 1.0 - beta
            a[i, (i + 1) % s] = beta
    dm = np.diag(np.r_[pd, np.ones(k)])
    dh = np.r_[1.0 - pd, np.zeros(k)]
    w, v = np.linalg.eig(a.T)
    pi = np.real(v[:, np.argmin(np.abs(w - 1.0))])
    return a, dm, dh, pi / pi.sum()


def log_vbw(b: np.ndarray, v: np.ndarray, w: np.ndarray, m: np.ndarray) -> np.ndarray:
    """log(v B^m w) for integer powers m, exact up to N_EXACT, then at the dominant eigenvalue's rate."""
    n_max = min(int(m.max()) if m.size else 0, N_EXACT)
    vals = np.empty(n_max + 1)
    x, scale = v.astype(float).copy(), 0.0
    for j in range(n_max + 1):  # a few hundred small products per evaluation
        vals[j] = np.log(max(float(x @ w), 1e-300)) + scale
        x = x @ b
        total = x.sum()
        if total <= 0:
            vals[j + 1:] = -690.0
            break
        x /= total
        scale += np.log(total)
    out = np.empty(m.size)
    small = m <= n_max
    out[small] = vals[m[small]]
    if (~small).any():
        out[~small] = vals[n_max] + (m[~small] - n_max) * np.log(np.max(np.abs(np.linalg.eigvals(b))))
    return out


def loglik(theta: np.ndarray, k: int, family: str, runs: tuple[np.ndarray, ...]) -> float:
    alpha, beta, pd = expit(theta)
    a, dm, dh, pi = chain(alpha, beta, pd, k, family)
    b = a @ dm
    up, one, ahd = np.eye(k + 1)[0], np.ones(k + 1), a @ dh
    ll = 0.0
    for arr, kind in zip(runs, ("internal", "leading", "trailing", "full"), strict=True):
        if not arr.size:
            continue
        vals, cnt = np.unique(arr, return_counts=True)
        if kind == "internal":
            p = log_vbw(b, up, ahd, vals)
        elif kind == "trailing":
            p = log_vbw(b, up, one, vals)
        elif kind == "leading":
            p = np.where(vals == 0, np.log(max(float(pi @ dh), 1e-300)),
                         log_vbw(b, pi @ dm, ahd, np.maximum(vals - 1, 0)))
        else:
            p = np.where(vals == 0, 0.0, log_vbw(b, pi @ dm, one, np.maximum(vals - 1, 0)))
        ll += float(np.sum(cnt * p))
    return ll


def best_fit(runs: tuple[np.ndarray, ...], k: int, family: str, start: np.ndarray | None) -> tuple[float, np.ndarray]:
    starts = [start] if start is not None else [logit([0.01, 0.3, 0.03]), logit([0.05, 0.5, 0.02])]
    res = min((minimize(lambda th: -loglik(th, k, family, runs), s, method="Nelder-Mead",
                        options={"xatol": 1e-6, "fatol": 1e-8, "maxiter": 3000}) for s in starts),
              key=lambda r: r.fun)
    return -float(res.fun), res.x


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT, help="hanyang-uwb folder")
    ap.add_argument("--max-k", type=int, default=4)
    args = ap.parse_args()
    rate = 10.0
    traces = [import_hanyang(args.data / "Dynamic_measurements" / r, crop_to_uwb=True)[0] for r in RUNS]
    tabs = [af.attempt_table(t, rate) for t in traces]
    ids = sorted({a for t in traces for a in t.anchors.ids})
    stats = {a: af.RunStats() for a in ids}
    for t, tab in zip(traces, tabs, strict=True):
        for j, aid in enumerate(t.anchors.ids):
            att = tab.attempted[:, j]
            af.add_runs(stats[aid], tab.t_s[att], np.where(tab.heard[:, j], 1, 0)[att])
    ks = range(1, args.max_k + 1)
    print("per-anchor log-likelihood over the four runs pooled (higher is better)")
    print("| anchor | calibration's chain | " + " | ".join(f"min {k}" for k in ks[1:]) + " | "
          + " | ".join(f"Erlang {k}" for k in ks[1:]) + " | missed-run lengths 1 / 2 / 3 / 4 |")
    print("|---|---|" + "---|" * (2 * (len(ks) - 1)) + "---|")
    for aid in ids:
        runs = stats[aid].arrays()
        ref = af.fit_dropout_outage(stats[aid], 1.0 / rate, rate)["log_likelihood"]
        row = {}
        for family in ("min", "Erlang"):
            start = None
            for k in ks:
                row[(family, k)], start = best_fit(runs, k, family if family == "min" else "erlang", start)
        hist = np.bincount(runs[0], minlength=5)[1:5]
        print(f"| {aid} | {ref:.1f} (here {row[('min', 1)]:.1f}) | "
              + " | ".join(f"{row[('min', k)]:.1f}" for k in ks[1:]) + " | "
              + " | ".join(f"{row[('Erlang', k)]:.1f}" for k in ks[1:]) + " | "
              + " / ".join(str(int(x)) for x in hist) + " |")


if __name__ == "__main__":
    main()
