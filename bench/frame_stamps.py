"""How well camera frames are stamped with their capture time (what the EKF fuses them at).

Loopback: the simulator streams H.264 over TCP at real time; the driver decodes; frames are
polled at 100 Hz as ``Vehicle`` does. The simulator's PaVE timestamp is its clock at render
time, mapped to the host clock by the least ``host − sim`` difference seen while polling. Each
frame is stamped three ways in the same run: ``FrameClock`` (PaVE timestamp + least offset), the
former fixed guess (receipt − 50 ms), and receipt itself. A second table replays a modelled
Wi-Fi link (least delay 30 ms plus exponential jitter, mean 40 ms; seeded), where the jitter
that a fixed guess cannot remove is larger.

    python bench/frame_stamps.py [--quick] [--json out.json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import random
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from drone.ardrone.driver import ARDroneDriver  # noqa: E402
from drone.ardrone.frame_clock import FrameClock  # noqa: E402
from drone.sim.server import SimServer  # noqa: E402
from drone.sim.world import load_world  # noqa: E402

ADDR = "127.0.0.151"
FIXED_LATENCY_S = 0.05  # the stamp used before FrameClock: receipt − 50 ms


async def loopback(seconds: float) -> list[tuple[int, float]]:
    """(PaVE timestamp ms, receipt on the simulator's clock) per frame, over real sockets."""
    srv = SimServer(ADDR, load_world("indoor"), seed=1)
    frames: list[tuple[int, float]] = []
    offsets: list[float] = []
    async with srv, ARDroneDriver(ADDR) as drv:
        await drv.wait_handshake(10.0)
        seen = drv.frames_decoded
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            now = time.monotonic()
            offsets.append(now - srv.sim.time)
            if drv.frames_decoded != seen and drv.latest_frame is not None:
                seen = drv.frames_decoded
                frames.append((drv.latest_frame_ms, now))
            await asyncio.sleep(0.01)
    offset = min(offsets)
    return [(ms, rx - offset) for ms, rx in frames]  # receipt on the simulator's clock


def wifi(n: int, seed: int = 1) -> list[tuple[int, float]]:
    rng = random.Random(seed)
    out = []
    for i in range(n):
        ms = round(i * 1000 / 15)
        out.append((ms, ms / 1000 + 0.030 + rng.expovariate(1 / 0.040)))
    return out


def errors(frames: list[tuple[int, float]]) -> dict[str, list[float]]:
    """Stamp − capture (s) per frame for each way of stamping; receipts on the drone's clock."""
    clock = FrameClock()
    out: dict[str, list[float]] = {"FrameClock": [], "receipt − 50 ms": [], "receipt": []}
    for ms, rx in frames:
        capture = ms / 1000
        out["FrameClock"].append(clock.stamp(ms, rx) - capture)
        out["receipt − 50 ms"].append(rx - FIXED_LATENCY_S - capture)
        out["receipt"].append(rx - capture)
    return out


def table(title: str, errs: dict[str, list[float]]) -> list[dict[str, float | str]]:
    """Bias (a constant, calibrated away by ``least_frame_delay_s``) and spread (not)."""
    base = statistics.pstdev(errs["receipt − 50 ms"])
    print(f"\n{title}\n")
    print(
        "| stamp | bias (median error) ms | spread (stdev) ms | p90 abs error ms | spread × fixed |"
    )
    print("|---|---|---|---|---|")
    rows: list[dict[str, float | str]] = []
    for name, e in errs.items():
        a = sorted(abs(x) for x in e)
        bias, sd, p90 = statistics.median(e), statistics.pstdev(e), a[int(0.9 * (len(a) - 1))]
        ratio = sd / base if base > 0 else float("nan")
        print(f"| {name} | {bias * 1e3:.1f} | {sd * 1e3:.1f} | {p90 * 1e3:.1f} | {ratio:.3f} |")
        rows.append({"stamp": name, "bias_ms": bias * 1e3, "sd_ms": sd * 1e3, "p90_ms": p90 * 1e3})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="3 s of video instead of 15 s")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    seconds = 3.0 if args.quick else 15.0
    frames = asyncio.run(loopback(seconds))
    skip = len(frames) // 5  # FrameClock learns the least delay in the first frames
    out = {
        "loopback": table(
            f"Loopback simulator, {len(frames) - skip} frames over {seconds:.0f} s (first "
            f"{skip} left out)",
            {k: v[skip:] for k, v in errors(frames).items()},
        ),
        "wifi_model": table(
            "Modelled Wi-Fi link, 900 frames (least delay 30 ms + exponential jitter, mean 40 ms)",
            {k: v[30:] for k, v in errors(wifi(930)).items()},
        ),
    }
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
