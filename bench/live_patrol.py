"""The Central patrol flown live in the console, against the lockstep experiment.

Starts a real ``uav-console serve --fleet 2 --world outdoor`` (vehicles in their own
processes), opens the console page in headless Chromium and presses the Central patrol's
"Start patrol (all drones)" as an operator does, then samples ``GET /api/v1/patrol`` (and each
drone's simulator truth) every ``--every`` seconds for ``--duration`` seconds. Every sample is
appended to a JSONL file as it comes (a run cut short still gives its figures: ``--report FILE``
reads one back). At the end it prints the console's coverage, longest coverage gap, handoffs and
lowest battery, the same figures from the lockstep experiment (``uav-console patrol``) of the same
length and seed, and the differences (the target: 1 percentage point of coverage, 5 s of
longest gap), with the CPU the run used (serve and its vehicle processes, Chromium, this script).

Coverage here is the console's own (``mission.coverage.route`` of ``GET /api/v1/patrol``: the
CTM samples the drones' reported positions against the route corridor); the truth samples give
a coarse second opinion (one look every ``--every`` seconds at the simulator's true positions).

Usage::

    PYTHONPATH=$PWD python bench/live_patrol.py --duration 7200 --out live.jsonl
    PYTHONPATH=$PWD python bench/live_patrol.py --report live.jsonl   # figures so far
    PYTHONPATH=$PWD python bench/live_patrol.py --duration 90 --clock-speed 8 --no-camera
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CHROMIUM = os.environ.get("UAVC_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
TOKEN = "live-patrol-bench-token"
CLK_TCK = os.sysconf("SC_CLK_TCK")
COVERAGE_PP = 1.0  # the target: coverage within 1 percentage point of the lockstep's
GAP_S = 5.0  # and the longest gap within 5 s


# ---------------------------------------------------------------------------- CPU accounting
def _stat(pid: int) -> tuple[int, float] | None:
    """(parent pid, CPU seconds of the process and its reaped children) from /proc."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    f = raw[raw.rindex(")") + 2 :].split()
    # fields after the name: state ppid … utime(12) stime(13) cutime(14) cstime(15)
    ticks = int(f[11]) + int(f[12]) + int(f[13]) + int(f[14])
    return int(f[1]), ticks / CLK_TCK


def tree_cpu_s(root: int) -> float:
    """CPU seconds of ``root`` and every live descendant (reaped ones via cutime/cstime)."""
    table: dict[int, tuple[int, float]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            st = _stat(int(d.name))
            if st is not None:
                table[int(d.name)] = st
    keep, frontier = {root}, [root]
    while frontier:
        p = frontier.pop()
        for pid, (ppid, _) in table.items():
            if ppid == p and pid not in keep:
                keep.add(pid)
                frontier.append(pid)
    return sum(table[p][1] for p in keep if p in table)


# ---------------------------------------------------------------------------- serve + page
@contextlib.contextmanager
def served(args: argparse.Namespace, data: Path) -> Iterator[tuple[subprocess.Popen[bytes], str]]:
    """``serve --fleet N --world outdoor`` with vehicle processes, until its drones are up."""
    from tests.support.loopback import free_port

    port = free_port()
    cmd = [sys.executable, "-m", "server", "serve", "--host", "127.0.0.1", "--port", str(port)]
    cmd += ["--token", TOKEN, "--data-dir", str(data), "--seed", str(args.seed)]
    cmd += ["--fleet", str(args.drones), "--world", "outdoor", "--sim-addr", args.sim_addr]
    if args.clock_speed != 1.0:
        cmd += ["--clock-speed", str(args.clock_speed)]
    if not args.camera:
        cmd += ["--no-camera"]
    env = {**os.environ, "UAVC_VEHICLES": "process", "PYTHONUNBUFFERED": "1"}
    log_path = data / "serve.log"
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120.0
        names = [f"uav{i + 1}" for i in range(args.drones)]
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"serve exited ({proc.returncode}):\n{log_path.read_text()}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"serve not healthy in 120 s:\n{log_path.read_text()[-3000:]}")
            with contextlib.suppress(httpx.HTTPError, ValueError):
                up = httpx.get(f"{base}/api/v1/health", timeout=2.0).json().get("drones", {})
                if all(up.get(n) for n in names):
                    break
            time.sleep(0.5)
        yield proc, base
    finally:
        proc.terminate()
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


def _until(page: Any, pred: Any, timeout_s: float, what: str) -> None:
    """Poll the page from here (the console's CSP forbids the string evaluation that
    Playwright's ``wait_for_function`` polls with)."""
    end = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > end:
            raise RuntimeError(f"timed out waiting for {what}")
        page.wait_for_timeout(250)


def press_start(page: Any, drones: int) -> str:
    """Wait until every drone is idle in the Central panel, open it, press Start; the reply."""
    _until(
        page,
        lambda: len(page.query_selector_all('#central-drones li[data-role="idle"]')) == drones,
        120.0,
        "every drone idle in the Central panel",
    )
    page.click("#central-h")
    replies = []
    for _ in range(10):  # as an operator does: read the reply, press again if it was refused
        page.click("#central-start")
        with contextlib.suppress(RuntimeError):
            _until(
                page,
                lambda: not str(page.text_content("#central-reply")).endswith("…"),
                30.0,
                "the patrol's start reply",
            )
        reply = str(page.text_content("#central-reply"))
        if reply.startswith("Starting the patrol"):
            return reply
        replies.append(reply)
        page.wait_for_timeout(3000)
    raise RuntimeError(f"the patrol did not start: {replies}")


def panel_text(page: Any) -> dict[str, str]:
    """What the Central panel shows (the operator's view of the same figures)."""
    out: dict[str, str] = {}
    for sel in ("central-state", "central-gap", "central-coverage", "central-cov-gap"):
        with contextlib.suppress(Exception):
            el = page.query_selector(f"#{sel}")
            if el is not None:
                out[sel] = str(el.text_content())
    return out


# ---------------------------------------------------------------------------- figures
def read_samples(path: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    head: dict[str, Any] = {}
    rows: list[dict[str, Any]] = []
    for line in path.read_text().splitlines():
        with contextlib.suppress(ValueError):
            obj = json.loads(line)
            if obj.get("kind") == "head":
                head = obj
            elif obj.get("kind") == "sample":
                rows.append(obj)
    return head, rows


def live_figures(head: dict[str, Any], rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The console's figures at the last sample, and the truth samples' coarse check."""
    unanswered = sum(1 for r in rows if "patrol" not in r)
    rows = [r for r in rows if "patrol" in r]  # a sample the server did not answer: skipped
    if not rows:
        raise SystemExit("no samples yet")
    last = rows[-1]
    m = last["patrol"].get("mission") or {}
    route = (m.get("coverage") or {}).get("route") or {}
    bat: dict[str, float] = {}
    for r in rows:
        for d in r["patrol"].get("drones", []):
            if d.get("battery") is not None:
                bat[d["name"]] = min(bat.get(d["name"], 101.0), float(d["battery"]))
        for n, t in r.get("truth", {}).items():
            if t and "battery_pct" in t:
                bat[n + " (truth)"] = min(bat.get(n + " (truth)", 101.0), float(t["battery_pct"]))
    on = [r.get("truth_on_route") for r in rows if r.get("truth_on_route") is not None]
    first = next((i for i, v in enumerate(on) if v), None)
    truth_cov = None if first is None else sum(on[first:]) / max(1, len(on) - first)
    return {
        "elapsed_s": last["t"],
        # the mission's own time (the console's clock) up to its latest coverage sample
        "sim_elapsed_s": (
            float(route["first_on_route_s"]) + float(route["window_s"])
            if route.get("first_on_route_s") is not None
            else last["t"] * head.get("clock_speed", 1.0)
        ),
        "state": last["patrol"].get("state"),
        "coverage_pct": route.get("coverage_pct"),
        "longest_gap_s": route.get("longest_gap_s"),
        "gaps": route.get("gaps"),
        "first_on_route_s": route.get("first_on_route_s"),
        "handoffs": m.get("handoffs"),
        "replacements": m.get("replacements"),
        "waypoint_longest_wait_s": (m.get("coverage") or {}).get("longest_gap_s"),
        "battery_min_pct": {k: round(v, 1) for k, v in sorted(bat.items())},
        "truth_sampled_coverage_pct": None if truth_cov is None else round(100 * truth_cov, 2),
        "cpu_s": last.get("cpu"),
        "unanswered_samples": unanswered,
        "panel": last.get("panel"),
        "samples": len(rows),
    }


def lockstep_figures(
    seconds: float, seed: int, drones: int, charge: float, handoff: str
) -> dict[str, Any]:
    from experiments.patrol import PatrolConfig, PatrolExperiment

    cfg = PatrolConfig(
        drones=drones, duration_s=seconds, seed=seed, charge_pct_s=charge, handoff=handoff
    )
    rep = PatrolExperiment(cfg).run()
    return {
        "duration_s": seconds,
        "coverage_pct": round(100 * rep.coverage, 2),
        "longest_gap_s": round(rep.max_gap_s, 1),
        "gaps": len(rep.gaps),
        "first_on_route_s": rep.first_on_route_s,
        "handoffs": rep.handoffs,
        "battery_min_pct": {k: round(v, 1) for k, v in rep.battery_min.items()},
        "wall_s": round(rep.wall_s, 1),
        "cpu_s": round(rep.cpu_s, 1),
    }


def report(path: Path, lockstep: bool = True) -> dict[str, Any]:
    head, rows = read_samples(path)
    live = live_figures(head, rows)
    out: dict[str, Any] = {"head": head, "live": live}
    print(f"live patrol ({path}): {live['samples']} samples, {live['elapsed_s']:.0f} s wall")
    for k, v in live.items():
        print(f"  {k:<28} {v}")
    # the lockstep mission starts when the button is pressed, so the same length is the
    # simulated time since then
    secs = float(live["sim_elapsed_s"])
    if lockstep and secs > 0:
        ls = lockstep_figures(
            secs,
            int(head.get("seed", 1)),
            int(head.get("drones", 2)),
            1.0,  # the outdoor world's pads charge at 1 %/s (worlds/outdoor.yaml)
            str(head.get("handoff", "predictive")),
        )
        out["lockstep"] = ls
        print(f"lockstep experiment, {secs:.0f} s, seed {head.get('seed', 1)}:")
        for k, v in ls.items():
            print(f"  {k:<28} {v}")
        if live["coverage_pct"] is not None:
            dc = float(live["coverage_pct"]) - ls["coverage_pct"]
            dg = float(live["longest_gap_s"]) - ls["longest_gap_s"]
            dh = int(live["handoffs"] or 0) - ls["handoffs"]
            out["diff"] = {"coverage_pp": round(dc, 2), "longest_gap_s": round(dg, 1)}
            ok = abs(dc) <= COVERAGE_PP and abs(dg) <= GAP_S
            print(
                f"differences (live - lockstep): coverage {dc:+.2f} pp, longest gap {dg:+.1f} s, "
                f"handoffs {dh:+d}   -> {'within' if ok else 'OUTSIDE'} "
                f"{COVERAGE_PP:g} pp / {GAP_S:g} s"
            )
    return out


# ---------------------------------------------------------------------------- the run
def truth_on_route(truths: dict[str, Any], route: list[dict[str, float]]) -> bool | None:
    """Is a drone flying on the route (2.5 m corridor, route height ± 1.5 m) in truth?"""
    if not route:
        return None
    from server.fleet.ctm import route_distance
    from server.fleet.geo import Enu

    pts = [Enu(p["x"], p["y"], p["z"]) for p in route]
    alt = pts[0].z
    for t in truths.values():
        if not t or not t.get("flying") or t.get("emergency"):
            continue
        p = Enu(float(t["x"]), float(t["y"]), float(t["z"]))
        if abs(p.z - alt) <= 1.5 and route_distance(p, pts, True) <= 2.5:
            return True
    return False


def run(args: argparse.Namespace) -> int:
    data = Path(tempfile.mkdtemp(prefix="uavc-live-patrol-"))
    out = args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    names = [f"uav{i + 1}" for i in range(args.drones)]
    cpu_me0 = time.process_time()
    with served(args, data) as (proc, base), out.open("w") as f:
        http = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {TOKEN}"})
        pw = browser = page = None
        if args.browser:
            from playwright.sync_api import sync_playwright

            pw = sync_playwright().start()
            browser = pw.chromium.launch(
                executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS
            )
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.goto(f"{base}/?token={TOKEN}")
            reply = press_start(page, args.drones)
        else:
            r = http.post("/api/v1/patrol", json={"handoff": args.handoff})
            r.raise_for_status()
            reply = r.json()["reply"]
        t0 = time.monotonic()
        cpu0 = tree_cpu_s(proc.pid)
        others0 = tree_cpu_s(os.getpid()) - cpu0 - time.process_time()
        head = {
            "kind": "head",
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "duration_s": args.duration,
            "seed": args.seed,
            "drones": args.drones,
            "clock_speed": args.clock_speed,
            "camera": args.camera,
            "handoff": args.handoff,
            "browser": args.browser,
            "reply": reply,
            "data_dir": str(data),
            "cores": os.cpu_count(),
        }
        f.write(json.dumps(head) + "\n")
        f.flush()
        print(f"started: {reply}", flush=True)
        route: list[dict[str, float]] = []
        next_t = 0.0
        while True:
            now = time.monotonic() - t0
            if now >= args.duration:
                break
            if proc.poll() is not None:
                print(f"serve died ({proc.returncode}); see {data}/serve.log", flush=True)
                break
            sample: dict[str, Any] = {"kind": "sample", "t": round(now, 2)}
            try:
                pat = http.get("/api/v1/patrol", timeout=10.0).json()
                m = pat.get("mission") or {}
                if not route and m.get("route"):
                    route = m["route"]
                for k in ("route", "route_geo"):
                    m.pop(k, None)
                cov = m.get("coverage") or {}
                for w in cov.get("waypoints", []):
                    for k in ("x", "y", "z"):
                        w.pop(k, None)
                sample["patrol"] = pat
                truths = {}
                for n in names:
                    tr = http.get(f"/api/v1/sim/{n}/truth", timeout=10.0)
                    truths[n] = tr.json() if tr.status_code == 200 else None
                sample["truth"] = {
                    n: None
                    if t is None
                    else {
                        k: t.get(k)
                        for k in ("x", "y", "z", "battery_pct", "flying", "emergency", "state")
                    }
                    for n, t in truths.items()
                }
                sample["truth_on_route"] = truth_on_route(truths, route)
            except (httpx.HTTPError, ValueError) as exc:
                sample["error"] = str(exc)
            if page is not None:
                sample["panel"] = panel_text(page)
            serve_s = tree_cpu_s(proc.pid) - cpu0
            me_s = time.process_time() - cpu_me0
            # everything else under this process: Playwright's driver and Chromium
            others = tree_cpu_s(os.getpid()) - tree_cpu_s(proc.pid) - time.process_time()
            sample["cpu"] = {
                "serve_tree_s": round(serve_s, 1),
                "browser_s": round(others - others0, 1),
                "bench_s": round(me_s, 1),
                "load1": round(os.getloadavg()[0], 2),
            }
            f.write(json.dumps(sample) + "\n")
            f.flush()
            if int(now) // 300 != int(next_t) // 300 or next_t == 0.0:
                m = sample.get("patrol", {}).get("mission") or {}
                rc = (m.get("coverage") or {}).get("route") or {}
                print(
                    f"{now:7.0f} s  {sample.get('patrol', {}).get('state')}  coverage "
                    f"{rc.get('coverage_pct')} %  longest gap {rc.get('longest_gap_s')} s  "
                    f"handoffs {m.get('handoffs')}  cpu {sample['cpu']}",
                    flush=True,
                )
            next_t = now + args.every
            time.sleep(max(0.0, next_t - (time.monotonic() - t0)))
        if browser is not None:
            with contextlib.suppress(Exception):
                browser.close()
        if pw is not None:
            with contextlib.suppress(Exception):
                pw.stop()
        http.close()
    report(out, lockstep=not args.no_lockstep)
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--duration", type=float, default=7200.0, help="wall seconds after Start")
    p.add_argument("--every", type=float, default=5.0, help="sample period (wall s)")
    p.add_argument("--out", type=Path, default=Path("live_patrol.jsonl"))
    p.add_argument("--drones", type=int, default=2)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--handoff", choices=("predictive", "reactive"), default="predictive")
    p.add_argument("--sim-addr", default="127.0.77.10", help="first simulated drone's address")
    p.add_argument(
        "--clock-speed", type=float, default=1.0, help="serve --clock-speed (server/timewarp.py)"
    )
    p.add_argument("--no-camera", dest="camera", action="store_false", help="serve --no-camera")
    p.add_argument("--no-browser", dest="browser", action="store_false", help="REST start")
    p.add_argument("--no-lockstep", action="store_true", help="skip the lockstep comparison")
    p.add_argument("--report", type=Path, default=None, help="figures of a JSONL file so far")
    args = p.parse_args(argv)
    if args.browser and args.handoff != "predictive":
        p.error("the console's button starts a predictive patrol; --handoff needs --no-browser")
    if args.report is not None:
        report(args.report, lockstep=not args.no_lockstep)
        return 0
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
