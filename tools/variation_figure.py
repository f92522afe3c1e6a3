"""Draw the sites a ``variation`` section gives the traces of ``walk-hanyang`` (docs/img/variation-walk.png).

    python tools/variation_figure.py [--n 12] [--seed 1] [--out docs/img/variation-walk.png]

Left: the preset as it is (one site: every trace on the calibrated route, at the first run's layout).
Right: a ``variation`` section (its defaults, the four layouts the calibration recorded, as
``generate --vary-site`` writes it,
plus ``random_route_prob`` 0.5 as the tracking study uses): every trace its own layout and route.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from physynth.generate import generate_traces  # noqa: E402
from physynth.io.scenario_file import load_scenario  # noqa: E402
from physynth.models.variation import SiteVariationParams, recorded_layouts  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "img" / "variation-walk.png")
    args = ap.parse_args()
    scn = load_scenario("walk-hanyang")
    varied = scn.model_copy(update={"variation": SiteVariationParams(
        layouts=recorded_layouts(scn.provenance, scn.anchor_ids), random_route_prob=0.5)})
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), sharex=True, sharey=True)
    for ax, s, title in ((axes[0], scn, "one site (the preset)"),
                         (axes[1], varied, "variation: 4 layouts, random routes 0.5")):
        for k, t in enumerate(generate_traces(s, args.n, seed=args.seed)):
            colour = f"C{k % 10}"
            ax.plot(t.truth.pos_enu_m[:, 0], t.truth.pos_enu_m[:, 1], lw=0.8, color=colour, alpha=0.8)
            ax.scatter(t.anchors.pos_enu_m[:, 0], t.anchors.pos_enu_m[:, 1], marker="^", s=22, color=colour,
                       edgecolor="k", linewidth=0.4, zorder=3)
        ax.set_title(f"{title}: {args.n} traces")
        ax.set_xlabel("east (m)")
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("north (m)")
    fig.suptitle("walk-hanyang: tag paths (lines) and anchor layouts (triangles), seed "
                 f"{args.seed}", fontsize=11)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
