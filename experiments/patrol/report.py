"""The patrol experiment's figures: one run's report (text, JSON, the plot) and the handoff
rules side by side."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from experiments.patrol.config import PatrolConfig
from experiments.patrol.metrics import Track


def _f(v: float | None) -> str:
    """A figure with one decimal, "-" for none."""
    return "-" if v is None else f"{v:.1f}"


@dataclass
class PatrolReport:
    """One run's figures, with the tracks and route the plot draws."""

    config: PatrolConfig
    duration_s: float
    first_on_route_s: float | None
    coverage: float
    max_gap_s: float
    gaps: list[tuple[float, float]]
    handoffs: int
    replacements: int
    revisit_s: dict[str, dict[str, float | None]]
    handoff_revisit: list[dict[str, Any]]  # per handoff: intervals straddling it (truth)
    battery_min: dict[str, float]
    bound: dict[str, Any]
    wall_s: float
    cpu_s: float  # process CPU time: the speed on an unloaded core
    events: list[str]
    tracks: dict[str, Track] = field(repr=False)
    route: list[tuple[float, float, float]] = field(repr=False, default_factory=list)

    @property
    def handoff_gap_s(self) -> float:
        """The longest coverage gap after the first drone reached the route: the gaps at
        handoffs (the reactive rule's, a late relief's)."""
        return max((b - a for a, b in self.gaps), default=0.0)

    @property
    def battery_lowest(self) -> float:
        """The lowest charge any drone reached."""
        return min(self.battery_min.values(), default=float("nan"))

    @property
    def realtime_factor(self) -> float:
        return self.duration_s / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def realtime_factor_cpu(self) -> float:
        return self.duration_s / self.cpu_s if self.cpu_s > 0 else math.inf

    def to_json(self) -> dict[str, Any]:
        return {
            "coverage": round(self.coverage, 5),
            "max_gap_s": round(self.max_gap_s, 2),
            "handoffs": self.handoffs,
            "replacements": self.replacements,
            "drones": self.config.drones,
            "duration_s": self.duration_s,
            "threshold": self.config.threshold,
            "first_on_route_s": self.first_on_route_s,
            "gaps": [[round(a, 2), round(b, 2)] for a, b in self.gaps],
            "revisit_s": self.revisit_s,
            "handoff_revisit": self.handoff_revisit,
            "continuity": self.config.continuity,
            "handoff": self.config.handoff,
            "handoff_gap_s": round(self.handoff_gap_s, 2),
            "battery_lowest_pct": round(self.battery_lowest, 1),
            "battery_min_pct": {k: round(v, 1) for k, v in self.battery_min.items()},
            "bound": self.bound,
            "fail_at_s": self.config.fail_at_s,
            "wall_s": round(self.wall_s, 2),
            "realtime_factor": round(self.realtime_factor, 1),
            "cpu_s": round(self.cpu_s, 2),
            "realtime_factor_cpu": round(self.realtime_factor_cpu, 1),
            "battery": {
                n: [[round(r[0], 1), round(r[4], 1)] for r in rows[:: max(1, len(rows) // 120)]]
                for n, rows in self.tracks.items()
            },
        }

    def format_text(self) -> str:
        c = self.config
        lines = [
            f"persistent patrol: {c.drones} drones, {self.duration_s:.0f} s simulated "
            f"in {self.wall_s:.1f} s wall ({self.realtime_factor:.0f}× real time; "
            f"{self.realtime_factor_cpu:.0f}× per CPU second), "
            f"handoff at {c.threshold:.0%} ({c.handoff})"
            + (f", failure ({c.fail_kind}) at {c.fail_at_s:.0f} s" if c.fail_at_s else ""),
            f"  first drone on the route after   {self.first_on_route_s or float('nan'):.1f} s",
            f"  coverage (from then on)          {100 * self.coverage:.2f} %",
            f"  longest gap                      {self.max_gap_s:.1f} s ({len(self.gaps)} gaps)",
            f"  handoffs                         {self.handoffs}",
            f"  replacements after failures      {self.replacements}",
            "  revisit time per waypoint (s)    mean / max",
        ]
        for wp, r in self.revisit_s.items():
            lines.append(
                f"    {wp:<30} {_f(r['mean'])} / {_f(r['max'])}  ({int(r['visits'] or 0)} visits)"
            )
        b = self.bound
        lines += [
            f"  drones persistent coverage needs {b['drones_needed']} "
            f"(bound: {b['on_route_s']:.0f} s on the route per {b['cycle_s']:.0f} s cycle; "
            f"best coverage with {c.drones}: "
            f"{100 * float(b['coverage_upper'].get(str(c.drones), 1.0)):.1f} %)",
            "  battery over time (%):",
        ]
        for name, rows in self.tracks.items():
            step = max(1, len(rows) // 12)
            pts = " ".join(f"{r[4]:.0f}" for r in rows[::step])
            lines.append(f"    {name}: {pts}   (min {self.battery_min[name]:.0f})")
        return "\n".join(lines)

    def plot(self, path: Path) -> None:
        """Tracks and batteries over time as a PNG (``experiments.patrol.plot``).

        Raises:
            RuntimeError: matplotlib (the ``report`` extra) is not installed.
        """
        from experiments.patrol.plot import plot_report

        plot_report(self, path)


def compare_text(reports: Sequence[PatrolReport]) -> str:
    """The handoff rules side by side (same seed, same everything else): the paper's reactive
    rule and the predictive one."""
    c = reports[0].config
    head = (
        f"handoff rules compared: {c.drones} drones, {c.duration_s:.0f} s simulated, seed "
        f"{c.seed}, handoff at {c.threshold:.0%}"
    )
    rows: list[tuple[str, list[Any], str]] = [
        ("", [r.config.handoff for r in reports], "{}"),
        ("coverage (%)", [100 * r.coverage for r in reports], "{:.2f}"),
        ("longest gap at a handoff (s)", [r.handoff_gap_s for r in reports], "{:.1f}"),
        ("gaps", [len(r.gaps) for r in reports], "{}"),
        ("handoffs", [r.handoffs for r in reports], "{}"),
        ("lowest battery (%)", [r.battery_lowest for r in reports], "{:.1f}"),
    ]
    lines = [head]
    for label, vals, fmt in rows:
        lines.append(f"  {label:<30}" + "".join(f"{fmt.format(v):>14}" for v in vals))
    return "\n".join(lines)
