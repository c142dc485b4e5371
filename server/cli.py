"""The ``uav-console`` command: serve, sim, vehicle, vehicle-key, interpret, patrol, bench, replay.

Each subcommand imports what it needs lazily, so ``interpret`` stays quick to start.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from server.settings import ROOT, Settings, SettingsError


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uav-console", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("serve", help="run the console (default: on the simulator)")
    s.add_argument("--host", default=None)
    s.add_argument("--port", type=int, default=None)
    s.add_argument(
        "--drone",
        default=None,
        help="'sim' (default), 'sim-mavlink', 'none', an AR.Drone's IP, or a MAVLink connection "
        "(tcp:HOST:PORT, udpin:0.0.0.0:14550, …); a fleet may list one per drone, comma-separated",
    )
    s.add_argument("--world", default=None, help="indoor | outdoor | path to a world file")
    s.add_argument("--fleet", type=int, default=None, help="number of simulated drones")
    s.add_argument("--token", default=None, help="pilot token (default: generated and stored)")
    s.add_argument("--observer-token", default=None)
    s.add_argument("--allow-origin", action="append", default=None, help="extra allowed Origin")
    s.add_argument("--rosbridge-port", type=int, default=None, help="also serve rosbridge here")
    s.add_argument("--data-dir", type=Path, default=None)
    s.add_argument("--seed", type=int, default=None)
    s.add_argument("--asr-model", type=Path, default=None, help="CTranslate2 Whisper directory")
    s.add_argument("--recognizer", choices=("server", "browser", "auto"), default=None)
    s.add_argument("--cert", type=Path, default=None, help="TLS certificate (PEM) for HTTPS")
    s.add_argument("--key", type=Path, default=None, help="its private key (PEM)")
    s.add_argument("--no-tls", action="store_true", help="plain HTTP even on a non-loopback --host")
    s.add_argument(
        "--sim-addr",
        default=None,
        help="the first simulated drone's loopback address (default 127.0.0.2, or the next "
        "free one when another console has it; env UAVC_SIM_BASE_ADDR)",
    )
    s.add_argument(
        "--vehicles",
        choices=("inline", "process"),
        default=None,
        help="each drone's flight stack, AR.Drone or MAVLink, in its own supervised process "
        "(process, the default) or in the web process (inline); env UAVC_VEHICLES",
    )

    s.add_argument(
        "--bus-listen",
        action="append",
        default=None,
        help="endpoint the bus router listens on (repeatable; default tcp/127.0.0.1:7447 or the "
        "next free port)",
    )
    s.add_argument(
        "--bus-connect", action="append", default=None, help="another bus router (repeatable)"
    )
    s.add_argument(
        "--bus-tls",
        choices=("auto", "on", "off"),
        default=None,
        help="TLS on the bus router's endpoints with the console's CA (auto: off loopback)",
    )
    s.add_argument(
        "--bus-credentials",
        type=Path,
        default=None,
        help="another console's DATA/bus/credentials.txt: share its bus users and passwords, "
        "to join its router (docs/failover.md)",
    )
    s.add_argument(
        "--bus-ca",
        type=Path,
        default=None,
        help="CA file the tls/ routers joined with --bus-connect are verified with (another "
        "console's DATA/tls/ca.pem; default: this data directory's)",
    )
    s.add_argument("--fleet-name", default=None, help="the fleet's name on the bus (default)")
    s.add_argument(
        "--console-name", default=None, help="this console's name on the bus (HOST-PORT)"
    )
    s.add_argument(
        "--clock-speed",
        type=float,
        default=None,
        help="run the console, its vehicles and simulators N times faster than the wall clock "
        "(tests, benchmarks; with --no-camera); env UAVC_CLOCK_SPEED",
    )
    s.add_argument(
        "--no-camera", action="store_true", help="read no video from the drones (env UAVC_CAMERA)"
    )

    sim = sub.add_parser("sim", help="the simulator alone, behind the AR.Drone protocol")
    sim.add_argument(
        "--addr", default=None, help="default 127.0.0.2 (AR.Drone), 127.0.0.9 (MAVLink)"
    )
    sim.add_argument("--world", default="indoor")
    sim.add_argument("--speed", type=float, default=1.0)
    sim.add_argument(
        "--protocol",
        choices=("ardrone", "mavlink"),
        default="ardrone",
        help="mavlink: a PX4-like autopilot on TCP 5760 (several clients) and UDP 14580",
    )
    sim.add_argument(
        "--insecure",
        action="store_true",
        help="mavlink: accept unsigned MAVLink (loopback addresses only; default: signed)",
    )
    sim.add_argument(
        "--print-key",
        action="store_true",
        help="mavlink: print the signing key as 64 hex digits (UAVC_MAVLINK_KEY) and exit",
    )
    sim.add_argument("--data-dir", type=Path, default=None, help="mavlink: where the key lives")

    v = sub.add_parser("vehicle", help="one drone's stack joining a central server")
    v.add_argument(
        "--central",
        default=None,
        help="ws://HOST:8000/rosbridge (a rosbridge central); without it the vehicle joins the "
        "bus (--bus-connect)",
    )
    v.add_argument("--name", required=True)
    v.add_argument("--drone", default="sim")
    v.add_argument(
        "--token",
        default=None,
        help="rosbridge central: the pilot token; /vehicle-link: only what the safety port checks",
    )
    v.add_argument(
        "--key-file",
        type=Path,
        default=None,
        help="/vehicle-link: this vehicle's own key (uav-console vehicle-key NAME on the console; "
        "else UAVC_VEHICLE_KEY)",
    )
    v.add_argument("--world", default=None, help="indoor | outdoor | a world file (UAVC_WORLD)")
    v.add_argument(
        "--bus-connect",
        action="append",
        default=None,
        help="the fleet's bus router to join as vehicle-NAME with this vehicle's key (repeatable)",
    )
    v.add_argument(
        "--bus-ca",
        type=Path,
        default=None,
        help="CA file a tls/ bus router is verified with (the console's DATA/tls/ca.pem; "
        "default: this data directory's)",
    )
    v.add_argument("--fleet-name", default=None, help="the fleet's name on the bus (default)")
    v.add_argument("--ca", type=Path, default=None, help="CA file for a wss:// central")
    v.add_argument("--fingerprint", default=None, help="pinned SHA-256 of the central's cert")
    v.add_argument("--prefix", default=None, help="topic prefix (default /NAME; '' for one drone)")
    v.add_argument("--index", type=int, default=None, help="simulator address / station index")
    v.add_argument("--safety-host", default="127.0.0.1", help="the safety door's address")
    v.add_argument("--safety-port", type=int, default=0, help="the safety door (0: any free)")
    v.add_argument("--safety-cert", type=Path, default=None, help="wss: safety door: its cert")
    v.add_argument("--safety-key", type=Path, default=None, help="wss: safety door: its key")
    v.add_argument("--parent-pid", type=int, default=None, help=argparse.SUPPRESS)

    from server.vehicles.key_cli import add_parser as add_vehicle_key

    add_vehicle_key(sub)

    i = sub.add_parser("interpret", help="NLU only: text -> JSON commands")
    i.add_argument("text", nargs="*")
    i.add_argument("--audio", nargs="+", metavar="FILE.wav", help="offline speech: WAV files")
    i.add_argument("--asr-model", type=Path, default=None, help="CTranslate2 Whisper directory")

    pa = sub.add_parser("patrol", help="persistent patrol experiment in lockstep", add_help=False)
    pa.add_argument("rest", nargs=argparse.REMAINDER)

    r = sub.add_parser("replay", help="the console, read-only, on a recorded flight (MCAP)")
    r.add_argument("file", type=Path, help="a recording (GET /api/v1/flights/{id})")
    r.add_argument("--speed", type=float, default=1.0, help="playback speed (default 1)")
    r.add_argument("--host", default=None)
    r.add_argument("--port", type=int, default=None)
    r.add_argument("--token", default=None, help="token for the page (default: generated)")
    r.add_argument("--recover", action="store_true", help="play a file cut short by a crash")
    r.add_argument("--paused", action="store_true", help="start paused at the beginning")

    b = sub.add_parser("bench", help="run the benchmarks in bench/ and print their tables")
    b.add_argument("names", nargs="*", help="bench modules (default: all)")
    b.add_argument("--quick", action="store_true")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    if argv is None:  # the installed script: before anything captures the clock
        from server import timewarp

        timewarp.install_from(args_list, os.environ)
    # `patrol` owns its flags (and --help); hand them over untouched.
    if args_list[:1] == ["patrol"]:
        from server.fleet.patrol import patrol_main

        return patrol_main(args_list[1:])
    args = _parser().parse_args(args_list)
    try:
        if args.command == "serve":
            return _serve(args)
        if args.command == "sim" and args.protocol == "mavlink":
            from server.vehicles.mavlink_stack import sim_main

            return sim_main(args)
        if args.command == "sim":
            from drone.sim.server import run_sim

            asyncio.run(run_sim(args.addr or "127.0.0.2", args.world, args.speed))
            return 0
        if args.command == "vehicle":
            if args.central is None or args.central.rstrip("/").endswith("/vehicle-link"):
                from server.vehicles.main import whole_vehicle_main

                return whole_vehicle_main(args)
            from server.fleet.client import vehicle_main

            return vehicle_main(args)
        if args.command == "vehicle-key":
            from server.vehicles.key_cli import vehicle_key_main

            return vehicle_key_main(args)
        if args.command == "interpret" and args.audio:
            from server.speech.cli import interpret_audio_main

            settings = Settings.from_env(asr_model=args.asr_model)
            return interpret_audio_main(
                list(args.text) + list(args.audio),
                sys.stdout,
                model_dir=settings.asr_model,
                model_sha256=settings.asr_model_sha256,
                window_s=settings.asr_window_s,
                beams=settings.asr_beams,
            )
        if args.command == "interpret":
            from server.language.cli import interpret_main

            return interpret_main(args.text, sys.stdin, sys.stdout)
        if args.command == "bench":
            return _bench(args.names, args.quick)
        if args.command == "replay":
            from server.recorder.replay_cli import replay_main

            return replay_main(args)
    except SettingsError as exc:
        print(f"uav-console: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 2


def serve_vehicles(flag: str | None, env: Mapping[str, str]) -> str:
    """Where ``serve`` runs each drone's flight stack: ``--vehicles``, else ``UAVC_VEHICLES``,
    else ``process`` (issue 14: its own supervised process, for AR.Drones and MAVLink drones
    alike). ``inline`` keeps it in the web process. ``Settings`` itself defaults to ``inline``:
    an app built in-process (tests, embedding) spawns nothing unless asked."""
    return flag or env.get("UAVC_VEHICLES") or "process"


def _serve(args: argparse.Namespace) -> int:
    import uvicorn

    from server.app import create_app
    from server.http.conn_guard import KEEP_ALIVE_S, ConnectionLimits, guarded_h11
    from server.http.ws_guard import preauth_capped_ws

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
        asr_model=args.asr_model,
        recognizer=args.recognizer,
        cert=args.cert,
        key=args.key,
        tls=False if args.no_tls else None,
        asr_preload=True,
        vehicles=serve_vehicles(args.vehicles, os.environ),
        bus_listen=tuple(args.bus_listen) if args.bus_listen else None,
        bus_connect=tuple(args.bus_connect) if args.bus_connect else None,
        bus_tls=args.bus_tls,
        bus_credentials=args.bus_credentials,
        bus_ca=args.bus_ca,
        fleet_name=args.fleet_name,
        console_name=args.console_name,
        sim_base_addr=args.sim_addr,
        camera=False if args.no_camera else None,
    )
    if settings.recognizer not in ("server", "browser", "auto"):
        raise SettingsError(
            f"recognizer must be server, browser or auto, not {settings.recognizer!r}"
        )
    from server.vehicles.mavlink_stack import drone_kind, is_mavlink

    kinds = [drone_kind(settings.drone, i) for i in range(max(1, settings.fleet))]
    for kind in kinds:  # a bad connection string: refused up front
        is_mavlink(kind)
    if settings.drone != "none":  # simulators on addresses nobody else holds (module simaddr)
        from server.vehicles.simaddr import choose_sim_base

        choice = choose_sim_base(settings, kinds, fixed=args.sim_addr is not None)
        if choice.note:
            print(f"uav-console: {choice.note}", flush=True)
            settings = settings.with_(sim_base_addr=choice.base)
    from server.http.tls import TLSError, tls_for

    try:
        tls_files = tls_for(settings)
    except TLSError as exc:
        raise SettingsError(str(exc)) from exc
    app = create_app(settings, announce=True)
    app.state.runtime.tls = tls_files
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level="warning",
        # uvicorn cuts off absurd frames; below this the endpoint answers with a status error.
        ws_max_size=4 * settings.max_frame_bytes,
        # before auth, 4 KB: refused at the frame header, unread (issue 14)
        ws=preauth_capped_ws(),
        ssl_certfile=str(tls_files.cert) if tls_files else None,
        ssl_keyfile=str(tls_files.key) if tls_files else None,
        # per-IP connection cap and a header deadline (slowloris; issue 14)
        http=guarded_h11(ConnectionLimits()),
        timeout_keep_alive=KEEP_ALIVE_S,
        # a faster clock (server/timewarp.py) scales asyncio's selector loop, not uvloop's
        loop="asyncio" if settings.clock_speed != 1.0 else "auto",
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
