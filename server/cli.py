"""The ``uav-console`` command: serve, sim, vehicle, interpret, patrol, bench.

Each subcommand imports what it needs lazily, so ``interpret`` stays quick to start.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

from server.settings import ROOT, Settings, SettingsError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uav-console", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("serve", help="run the console (default: on the simulator)")
    s.add_argument("--host", default=None)
    s.add_argument("--port", type=int, default=None)
    s.add_argument("--drone", default=None, help="'sim' (default), 'none', or a drone's IP")
    s.add_argument("--world", default=None, help="indoor | outdoor | path to a world file")
    s.add_argument("--fleet", type=int, default=None, help="number of simulated drones")
    s.add_argument("--token", default=None, help="pilot token (default: generated and stored)")
    s.add_argument("--observer-token", default=None)
    s.add_argument("--allow-origin", action="append", default=None, help="extra allowed Origin")
    s.add_argument("--rosbridge-port", type=int, default=None, help="also serve rosbridge here")
    s.add_argument("--data-dir", type=Path, default=None)
    s.add_argument("--seed", type=int, default=None)

    sim = sub.add_parser("sim", help="the simulator alone, behind the AR.Drone protocol")
    sim.add_argument("--addr", default="127.0.0.2")
    sim.add_argument("--world", default="indoor")
    sim.add_argument("--speed", type=float, default=1.0)

    v = sub.add_parser("vehicle", help="one drone's stack joining a central server")
    v.add_argument("--central", required=True, help="ws://HOST:8000/rosbridge")
    v.add_argument("--name", required=True)
    v.add_argument("--drone", default="sim")
    v.add_argument("--token", default=None)
    v.add_argument("--world", default="outdoor")

    i = sub.add_parser("interpret", help="NLU only: text -> JSON commands")
    i.add_argument("text", nargs="*")

    pa = sub.add_parser("patrol", help="persistent patrol experiment in lockstep", add_help=False)
    pa.add_argument("rest", nargs=argparse.REMAINDER)

    b = sub.add_parser("bench", help="run the benchmarks in bench/ and print their tables")
    b.add_argument("names", nargs="*", help="bench modules (default: all)")
    b.add_argument("--quick", action="store_true")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    # `patrol` owns its flags (and --help); hand them over untouched.
    if args_list[:1] == ["patrol"]:
        from server.fleet.patrol import patrol_main

        return patrol_main(args_list[1:])
    args = _parser().parse_args(args_list)
    try:
        if args.command == "serve":
            return _serve(args)
        if args.command == "sim":
            from drone.sim.server import run_sim

            asyncio.run(run_sim(args.addr, args.world, args.speed))
            return 0
        if args.command == "vehicle":
            from server.fleet.client import vehicle_main

            return vehicle_main(args)
        if args.command == "interpret":
            from server.language.cli import interpret_main

            return interpret_main(args.text, sys.stdin, sys.stdout)
        if args.command == "bench":
            return _bench(args.names, args.quick)
    except SettingsError as exc:
        print(f"uav-console: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 2


def _serve(args: argparse.Namespace) -> int:
    import uvicorn

    from server.app import create_app

    settings = Settings.from_env(
        host=args.host,
        port=args.port,
        drone=args.drone,
        world=args.world,
        fleet=args.fleet,
        token=args.token,
        observer_token=args.observer_token,
        allow_origins=tuple(args.allow_origin) if args.allow_origin else None,
        rosbridge_port=args.rosbridge_port,
        data_dir=args.data_dir,
        seed=args.seed,
    )
    app = create_app(settings, announce=True)
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level="warning",
        # uvicorn cuts off absurd frames; below this the endpoint answers with a status error.
        ws_max_size=4 * settings.max_frame_bytes,
    )
    # uvicorn shuts down gracefully on Ctrl-C, then re-raises it: that is a normal exit.
    with contextlib.suppress(KeyboardInterrupt):
        uvicorn.Server(config).run()
    return 0


def _bench(names: list[str], quick: bool) -> int:
    bench_dir = ROOT / "bench"
    if not bench_dir.is_dir():
        print(
            f"uav-console bench: no benchmarks at {bench_dir}; they run from a source checkout",
            file=sys.stderr,
        )
        return 2
    scripts = sorted(p for p in bench_dir.glob("*.py") if not p.name.startswith("_"))
    if names:
        scripts = [p for p in scripts if p.stem in names]
    status = 0
    for script in scripts:
        print(f"\n## bench/{script.name}\n", flush=True)
        cmd = [sys.executable, str(script)] + (["--quick"] if quick else [])
        status |= subprocess.call(cmd, cwd=ROOT)
    return status


if __name__ == "__main__":
    raise SystemExit(main())
