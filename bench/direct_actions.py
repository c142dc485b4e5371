"""What the checks and the audit cost a direct action, measured on the real stack.

``POST /api/v1/drones/uav1/emergency`` goes through ``server.vehicles.direct_actions.perform``:
preflight check, the command to the driver, the dialog told, an audit row written (SQLite,
``synchronous=FULL``). The baseline, in the same run on the same app, is ``DroneStack.direct``
alone. Both are timed from the call to (a) the return and (b) the
drone's emergency bit in navdata (the simulator over the real AR.Drone protocol on loopback),
alternating, with a reset in between.

    python bench/direct_actions.py [--quick]
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from server.runtime import Runtime  # noqa: E402
from server.settings import Settings  # noqa: E402
from server.vehicles.direct_actions import perform  # noqa: E402

ADDR = "127.0.18.50"


async def until(pred: object, timeout_s: float = 5.0) -> float:
    t0 = time.perf_counter()
    while not pred():  # type: ignore[operator]
        if time.perf_counter() - t0 > timeout_s:
            raise TimeoutError("condition not reached")
        await asyncio.sleep(0.001)
    return time.perf_counter()


async def run(n: int) -> dict[str, list[float]]:
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(
            data_dir=Path(tmp), token="b", sim_base_addr=ADDR, vehicles="inline", asr_preload=False
        )
        rt = Runtime(settings)  # the drone in this process: the calls are measured in it
        await rt.start()
        try:
            stack = rt.drones["uav1"]
            await until(lambda: stack.vehicle.snapshot().link_ok, 20.0)
            out: dict[str, list[float]] = {
                k: [] for k in ("new_call", "new_bit", "old_call", "old_bit")
            }
            for i in range(2 * n):
                new = i % 2 == 0
                t0 = time.perf_counter()
                if new:
                    perform(
                        stack,
                        rt.dialogs["uav1"],
                        rt.audit,
                        "emergency",
                        source="rest",
                        battery_low_pct=rt.settings.battery_low_pct,
                    )
                else:
                    stack.direct("emergency")
                t1 = time.perf_counter()
                t2 = await until(lambda: stack.vehicle.snapshot().emergency, 20.0)
                key = "new" if new else "old"
                out[f"{key}_call"].append((t1 - t0) * 1000)
                out[f"{key}_bit"].append((t2 - t0) * 1000)
                await asyncio.sleep(0.3)
                stack.direct("reset")
                await until(lambda: not stack.vehicle.snapshot().emergency, 20.0)
                await asyncio.sleep(0.3)
            return out
        finally:
            await rt.stop()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    res = asyncio.run(run(10 if args.quick else 40))
    med = {k: statistics.median(v) for k, v in res.items()}
    print("| path | call returns (ms, median) | emergency bit in navdata (ms, median) |")
    print("|---|---|---|")
    print(f"| checked + audited (now) | {med['new_call']:.2f} | {med['new_bit']:.1f} |")
    print(f"| direct only (before, baseline) | {med['old_call']:.2f} | {med['old_bit']:.1f} |")
    ratio_call = med["new_call"] / med["old_call"]
    print(f"| ratio | {ratio_call:.1f} | {med['new_bit'] / med['old_bit']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
