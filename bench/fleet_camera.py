"""Each drone's camera in the console page with a fleet: frames per second and latency.

Starts ``uav-console serve --fleet N`` (vehicle processes, as an operator runs it), opens the
console in Debian's headless Chromium, flies every drone up to hover ("all drones take off")
and, for each drone in turn, selects it and samples what the page shows for ``--seconds``:

  fps       frames shown per second (CameraPanel.fps(), sampled every 0.5 s)
  arrival   server stamp of the frame -> the page receives it (the wire and the browser's queue)
  display   server stamp of the frame -> the page has decoded and shown it (what the HUD says)

Baselines in the same run: one drone (``--fleets 1,2``), and with ``--before CHECKOUT`` the
same fleets on another checkout's server and page (e.g. ``git worktree add /tmp/main main``),
back to back; the last column is each row's display latency over its baseline's. Targets:
with two drones each camera keeps >= 10 fps and <= 200 ms ("target" column). The
stamp is taken when the vehicle has encoded the JPEG (server/nodes/vehicle_node.py; over the bus
it travels as the frame's attachment), so the bus, the console and the page are included,
rendering and perception are not. "throttle at end" is the page's camera throttle
(camera_feed.js) when sampling ended.

Usage: ``python bench/fleet_camera.py [--fleets 1,2] [--seconds 10] [--vehicles process]
[--root CHECKOUT] [--before CHECKOUT]``. The defaults take about 2 minutes on an idle 2-core
machine (``--before`` twice that, less with ``--fleets 2``); the load average is printed beside
the figures, which are only worth reporting from a quiet machine.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
CHROMIUM = os.environ.get("UAVC_CHROMIUM", "/usr/bin/chromium")
TOKEN = "bench-fleet-camera"
TARGET_FPS, TARGET_MS = 10.0, 200.0  # with two drones

# Collects, in the page, the arrival and display latency of every frame of the selected drone.
PROBE = """
(() => {
  const cam = uavConsole.camera;
  window.__cam = { arrival: [], display: [], fps: [] };
  if (!cam.__probed) {
    cam.__probed = true;
    const onImage = cam.onImage.bind(cam);
    cam.onImage = (msg) => {
      const s = msg?.header?.stamp;
      const t = s ? (s.sec ?? s.secs) + (s.nanosec ?? s.nsecs ?? 0) / 1e9 : null;
      if (t) window.__cam.arrival.push((cam.serverNow() - t) * 1000);
      onImage(msg);
    };
  }
  let seen = cam.frames;
  window.__camTimer = setInterval(() => {
    window.__cam.fps.push(cam.fps());
    if (cam.frames !== seen && cam.latencies.length) {
      window.__cam.display.push(cam.latencies[cam.latencies.length - 1]);
      seen = cam.frames;
    }
  }, 500);
})();
"""


def start_server(
    fleet: int, vehicles: str, data: Path, port: int, root: Path = ROOT
) -> subprocess.Popen[bytes]:
    env = dict(
        os.environ,
        PYTHONPATH=str(root),
        UAVC_VEHICLES=vehicles,
        UAVC_SIM_BASE_ADDR="127.0.0.160",
        PYTHONUNBUFFERED="1",
    )
    cmd = [sys.executable, "-m", "server", "serve", "--port", str(port), "--token", TOKEN]
    cmd += ["--data-dir", str(data), "--fleet", str(fleet), "--seed", "1"]
    log = (data / "serve.log").open("wb")
    proc = subprocess.Popen(cmd, cwd=root, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 300  # minutes on a loaded 2-core machine
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError((data / "serve.log").read_text()[-3000:])
        try:
            r = httpx.get(f"{base}/api/v1/health", timeout=1)
            if r.status_code == 200 and all(r.json()["drones"].values()):
                return proc
        except httpx.HTTPError:
            pass
        time.sleep(0.3)
    proc.terminate()
    raise RuntimeError("server did not start")


def p50(xs: list[float]) -> float:
    return statistics.median(xs) if xs else float("nan")


def measure(
    fleet: int, vehicles: str, seconds: float, browser: Any, root: Path = ROOT
) -> list[dict[str, Any]]:
    from tests.support.loopback import free_port

    with tempfile.TemporaryDirectory() as tmp:
        port = free_port()
        proc = start_server(fleet, vehicles, Path(tmp), port, root)
        try:
            ctx = browser.new_context(viewport={"width": 1280, "height": 800}, bypass_csp=True)
            page = ctx.new_page()
            page.goto(f"http://127.0.0.1:{port}/?token={TOKEN}")
            page.wait_for_selector("#conn[data-state='open']", timeout=120_000)
            page.wait_for_function("uavConsole.haveLease === true", timeout=120_000)
            page.fill("#text-input", "all drones take off" if fleet > 1 else "take off")
            page.press("#text-input", "Enter")
            page.wait_for_timeout(6000)  # up and hovering
            rows = []
            names = [f"uav{i + 1}" for i in range(fleet)]
            for name in names:
                if fleet > 1:
                    page.select_option("#drone-select", name)
                page.wait_for_timeout(2000)
                page.evaluate(PROBE)
                page.wait_for_timeout(int(seconds * 1000))
                got = page.evaluate("clearInterval(window.__camTimer), window.__cam")
                throttle = page.evaluate(
                    "uavConsole.cameraFeed ? uavConsole.cameraFeed.throttleMs : null"
                )
                rows.append(
                    {
                        "fleet": fleet,
                        "drone": name,
                        "fps": p50(got["fps"]),
                        "arrival": p50(got["arrival"]),
                        "display": p50(got["display"]),
                        "frames": len(got["arrival"]),
                        "throttle": throttle,
                    }
                )
            page.fill("#text-input", "all drones land" if fleet > 1 else "land")
            page.press("#text-input", "Enter")
            page.wait_for_timeout(1000)
            ctx.close()
            return rows
        finally:
            proc.terminate()
            try:
                proc.wait(15)
            except subprocess.TimeoutExpired:
                proc.kill()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    ap.add_argument("--fleets", default="1,2", help="fleet sizes to run, baseline first")
    ap.add_argument("--seconds", type=float, default=10.0, help="sampling time per drone")
    ap.add_argument("--vehicles", default="process", choices=["process", "inline"])
    ap.add_argument("--quick", action="store_true", help="6 s per drone")
    ap.add_argument("--root", type=Path, default=ROOT, help="checkout whose server to run")
    ap.add_argument("--before", type=Path, help="also run this checkout's server, first")
    args = ap.parse_args()
    seconds = 6.0 if args.quick else args.seconds
    from playwright.sync_api import sync_playwright

    roots = ([("before", args.before)] if args.before else []) + [("now", args.root)]
    rows: list[dict[str, Any]] = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=CHROMIUM, headless=True, args=["--no-sandbox", "--disable-gpu"]
        )
        try:
            for label, root in roots:
                for n in (int(x) for x in args.fleets.split(",")):
                    rows += [
                        {**r, "code": label}
                        for r in measure(n, args.vehicles, seconds, browser, root)
                    ]
        finally:
            browser.close()
    load = os.getloadavg()[0]
    print(
        f"\nCamera in the page ({args.root}), vehicles={args.vehicles}, {seconds:g} s per drone,"
        f" load {load:.1f} on {os.cpu_count()} cores"
    )
    print(
        "| code | fleet | drone | fps p50 | arrival p50 | display p50 | frames | throttle at end |"
        " target | display / baseline |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        # baseline: the before code's same drone where it ran, else this code's first row
        base = next(
            (
                b
                for b in rows
                if b["code"] == "before" and (b["fleet"], b["drone"]) == (r["fleet"], r["drone"])
            ),
            rows[0] if r["code"] == "now" and not args.before else None,
        )
        ratio = r["display"] / base["display"] if base and base["display"] else float("nan")
        throttle = "–" if r["throttle"] is None else f"{r['throttle']} ms"
        met = r["fps"] >= TARGET_FPS and r["display"] <= TARGET_MS
        target = ("met" if met else "NOT met") if r["fleet"] >= 2 else "–"
        print(
            f"| {r['code']} | {r['fleet']} | {r['drone']} | {r['fps']:.1f} | {r['arrival']:.0f} ms"
            f" | {r['display']:.0f} ms | {r['frames']} | {throttle} | {target} | {ratio:.2f} |"
        )


if __name__ == "__main__":
    main()
