"""The vehicle process's weight: start-up time and peak RSS of one whole vehicle
(simulator, driver, vehicle, task executor, supervisor, LTM, safety door) started in a fresh
interpreter, and which web-stack modules it loaded; a baseline checkout and this one, runs
interleaved in the same session, medians printed with their ratio.

Usage: ``python bench/lean_vehicle.py [--baseline PATH] [--runs N]`` (``--baseline``: the root
of another checkout of this project, e.g. ``main``; its code is imported through PYTHONPATH
with this checkout's probe, tests/isolation/lean_probe.py). The machine is shared: ``uptime``
is printed with the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PROBE = ROOT / "tests" / "isolation" / "lean_probe.py"


def run_once(code_root: Path, addr: str) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as data:
        env = {**os.environ, "PYTHONPATH": str(code_root)}
        out = subprocess.run(
            [sys.executable, str(PROBE), addr, data],
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
            check=True,
        )
    result: dict[str, Any] = json.loads(out.stdout.strip().splitlines()[-1])
    return result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--baseline", type=Path, default=None)
    ap.add_argument("--runs", type=int, default=3)
    args = ap.parse_args()
    roots = {"this": ROOT} if args.baseline is None else {"baseline": args.baseline, "this": ROOT}
    results: dict[str, list[dict[str, Any]]] = {k: [] for k in roots}
    for i in range(args.runs):
        for k, root in roots.items():
            results[k].append(run_once(root, f"127.0.0.{62 + i % 4}"))
    print(subprocess.run(["uptime"], capture_output=True, text=True, check=False).stdout.strip())
    print(f"{'checkout':<10} {'start-up s':>11} {'peak RSS MB':>12} {'modules':>8}  loaded")
    med: dict[str, tuple[float, float]] = {}
    for k, rows in results.items():
        s = statistics.median(r["startup_s"] for r in rows)
        m = statistics.median(r["rss_mb"] for r in rows)
        n = statistics.median(r["modules"] for r in rows)
        med[k] = (s, m)
        print(f"{k:<10} {s:>11.2f} {m:>12.1f} {n:>8.0f}  {sorted(rows[-1]['loaded'])}")
    if "baseline" in med:
        (s0, m0), (s1, m1) = med["baseline"], med["this"]
        print(f"{'ratio':<10} {s1 / s0:>11.2f} {m1 / m0:>12.2f}")


if __name__ == "__main__":
    main()
