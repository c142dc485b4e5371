"""Run in a fresh interpreter by tests/isolation/test_lean_vehicle.py and bench/lean_vehicle.py:
start one whole vehicle (simulator, driver, vehicle, task executor, supervisor, LTM, safety
door) as ``uav-console vehicle`` does, then print one JSON line: which web-stack modules it
loaded, its start-up time and its peak RSS. It never reaches a console (none is running)."""

from __future__ import annotations

import time

T0 = time.perf_counter()

import asyncio  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
from typing import Any  # noqa: E402

# What the vehicle process must not carry (issue 27): the web stack and the console's parts.
ABSENT = {
    "fastapi": "fastapi",
    "onnxruntime": "onnxruntime",
    "nlu": "server.language",
    "dialog": "server.dialog",
    "speech": "server.speech",
    "captioner": "server.captioner",
    "recorder": "server.recorder",
}


async def main(addr: str, data_dir: str) -> dict[str, object]:
    from server.settings import Settings
    from server.vehicles.host import VehicleHost, VehicleOptions

    # Port 9 (the discard service's), where no console listens: bench/lean_vehicle.py runs this
    # probe against other checkouts too (a vehicle on the bus, or on a vehicle link before
    # there was a bus), so it imports nothing from tests/.
    bus: dict[str, Any] = {}
    if "bus_connect" in Settings.model_fields:
        bus["bus_connect"] = ("tcp/127.0.0.1:9",)
    settings = Settings.from_env(drone="sim", world="indoor", data_dir=data_dir, **bus)
    settings = settings.with_(sim_base_addr=addr)
    fields = getattr(VehicleOptions, "__dataclass_fields__", {})
    link: dict[str, Any] = {}
    if "central" in fields:
        link["central"] = "ws://127.0.0.1:9/vehicle-link"
    options = VehicleOptions(name="uav1", prefix="", **link)
    host = VehicleHost(settings, options, "k" * 43, safety_token="probe-token")
    await host.start()
    started_s = time.perf_counter() - T0
    loaded = {
        part: name
        for part, name in ABSENT.items()
        if any(m == name or m.startswith(name + ".") for m in sys.modules)
    }
    await host.stop()
    return {
        "loaded": loaded,
        "startup_s": started_s,
        "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "modules": len(sys.modules),
    }


if __name__ == "__main__":
    print(json.dumps(asyncio.run(main(sys.argv[1], sys.argv[2]))))
    sys.stdout.flush()
    os._exit(0)
