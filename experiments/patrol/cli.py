"""``uav-console patrol``: the patrol experiment's flags, one run or the handoff rules compared."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

from experiments.patrol.config import PatrolConfig
from experiments.patrol.report import compare_text
from experiments.patrol.run import PatrolExperiment

DESCRIPTION = (
    "The persistent-patrol experiment: the paper's mission flown in lockstep, measured, plotted."
)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uav-console patrol", description=DESCRIPTION)
    p.add_argument("--drones", type=int, default=2)
    p.add_argument("--duration", type=float, default=3600.0, help="simulated seconds")
    p.add_argument("--threshold", type=float, default=0.30, help="handoff battery fraction")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--png", type=Path, default=None, help="write tracks and batteries here")
    p.add_argument("--fail-at", type=float, default=None, help="the patrolling drone fails at S")
    p.add_argument("--fail-kind", choices=("emergency", "link"), default="emergency")
    p.add_argument("--swap", type=float, default=120.0, help="station battery swap time (s)")
    p.add_argument("--charge-rate", type=float, default=None, help="charge at %%/s instead")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dt", type=float, default=0.1, help="lockstep tick (s)")
    p.add_argument("--events", action="store_true", help="also print the CTM's event log")
    p.add_argument("--protocol", choices=("ardrone", "mavlink"), default="ardrone")
    p.add_argument(
        "--handoff",
        choices=("predictive", "reactive", "both"),
        default="predictive",
        help="predictive: the relief is on the route before the threshold; reactive: the "
        "paper's rule, leave at the threshold and send the relief then; both: fly both on "
        "the same seed and report them side by side",
    )
    return p


def patrol_main(argv: Sequence[str]) -> int:
    """``uav-console patrol``; returns the exit status (2: bad arguments)."""
    args = _parser().parse_args(list(argv))
    if not 0.0 < args.threshold < 1.0:
        print("uav-console patrol: --threshold must be in (0, 1)", file=sys.stderr)
        return 2
    rules = ("reactive", "predictive") if args.handoff == "both" else (args.handoff,)
    try:
        exps = [
            PatrolExperiment(
                PatrolConfig(
                    drones=args.drones,
                    duration_s=args.duration,
                    threshold=args.threshold,
                    seed=args.seed,
                    dt=args.dt,
                    swap_s=args.swap,
                    charge_pct_s=args.charge_rate,
                    fail_at_s=args.fail_at,
                    fail_kind=args.fail_kind,
                    protocol=args.protocol,
                    handoff=rule,
                )
            )
            for rule in rules
        ]
    except ValueError as exc:
        print(f"uav-console patrol: {exc}", file=sys.stderr)
        return 2
    if len(exps) > 1:
        reports = [e.run() for e in exps]
        if args.json:
            print(json.dumps({r.config.handoff: r.to_json() for r in reports}))
        else:
            print(compare_text(reports))
        return 0
    report = exps[0].run()
    if args.png is not None:
        report.plot(args.png)
    if args.json:
        print(json.dumps(report.to_json()))
    else:
        print(report.format_text())
        if args.png is not None:
            print(f"  figure: {args.png}")
        if args.events:
            print("events:")
            print("\n".join("  " + e for e in report.events))
    return 0
