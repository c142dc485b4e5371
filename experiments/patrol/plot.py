"""The patrol report as a figure: tracks in the map frame (route, stations) and batteries over
time, with the coverage gaps shaded. Needs matplotlib (the ``report`` extra)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from experiments.patrol.report import PatrolReport


def plot_report(report: PatrolReport, path: Path) -> None:
    """Write ``report``'s tracks and batteries to ``path`` (PNG).

    Raises:
        RuntimeError: matplotlib (the ``report`` extra) is not installed.
    """
    try:
        import matplotlib
    except ImportError as exc:
        raise RuntimeError(
            "the patrol plot needs matplotlib: pip install 'uav-console[report]'"
        ) from exc

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5.5), dpi=100)
    rx = [p[0] for p in report.route] + [report.route[0][0]]
    ry = [p[1] for p in report.route] + [report.route[0][1]]
    ax1.plot(rx, ry, "k--", lw=1.5, label="route")
    for name, rows in report.tracks.items():
        line = ax1.plot([r[1] for r in rows], [r[2] for r in rows], lw=0.8, label=name)
        ax2.plot(
            [r[0] / 60 for r in rows],
            [r[4] for r in rows],
            color=line[0].get_color(),
            label=name,
        )
    ax1.set_aspect("equal")
    ax1.set_xlabel("east (m)")
    ax1.set_ylabel("north (m)")
    ax1.set_title("tracks (simulator truth)")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.axhline(100 * report.config.threshold, color="grey", ls=":", label="handoff threshold")
    for a, b in report.gaps:
        ax2.axvspan(a / 60, b / 60, color="red", alpha=0.3)
    ax2.set_xlabel("time (min)")
    ax2.set_ylabel("battery (%)")
    ax2.set_ylim(0, 105)
    ax2.set_title(
        f"coverage {100 * report.coverage:.2f} %, longest gap {report.max_gap_s:.1f} s, "
        f"{report.handoffs} handoffs"
    )
    ax2.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
