"""The ``uav-console`` command: serve, sim, vehicle, vehicle-key, interpret, patrol, bench, replay.

Each subcommand imports what it needs lazily, so ``interpret`` stays quick to start.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import os
import re
import socket
import subprocess
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

from pydantic import TypeAdapter, ValidationError

from server.settings import (
    ENV_PREFIX,
    ROOT,
    Settings,
    SettingsError,
    Shape,
    flags_of,
    group_of,
    shape_of,
)

# A vehicle joins its console's bus only: a ``vehicle --central URL`` (a rosbridge central) is
# refused in one line that says what to give instead, before argparse, which would read
# ``--central`` as an ambiguous prefix of ``--central-grace-s`` and ``--central-loss-land-s``.
CENTRAL_FLAG = "--central"
CENTRAL_REFUSAL = (
    "uav-console vehicle: a vehicle joins its console over the bus: --bus-connect ENDPOINT "
    "(serve prints it: 'bus: tcp/…'), not --central"
)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="uav-console", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("serve", help="run the console (default: on the simulator)")
    add_setting_flags(s)

    sim = sub.add_parser("sim", help="the simulator alone, behind the AR.Drone protocol")
    sim.add_argument(
        "--addr", default=None, help="default 127.0.0.2 (AR.Drone), 127.0.0.9 (MAVLink)"
    )
    sim.add_argument("--world", default=Settings.model_fields["world"].default)
    sim.add_argument("--speed", type=float, default=Settings.model_fields["sim_speed"].default)
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

    v = sub.add_parser(
        "vehicle",
        help="one drone's stack joining a console's bus",
        description="One drone's whole flight stack, joining a console's bus "
        "(--bus-connect ENDPOINT). Settings come from UAVC_* variables and the flags below.",
    )
    v.add_argument("--name", required=True)
    v.add_argument(
        "--key-file",
        type=Path,
        default=None,
        help="this vehicle's own key, its bus password (uav-console vehicle-key NAME on the "
        "console; else UAVC_VEHICLE_KEY)",
    )
    v.add_argument("--prefix", default=None, help="topic prefix (default /NAME; '' for one drone)")
    v.add_argument("--index", type=int, default=None, help="simulator address / station index")
    v.add_argument("--safety-host", default="127.0.0.1", help="the safety door's address")
    v.add_argument("--safety-port", type=int, default=0, help="the safety door (0: any free)")
    v.add_argument("--safety-cert", type=Path, default=None, help="wss: safety door: its cert")
    v.add_argument("--safety-key", type=Path, default=None, help="wss: safety door: its key")
    v.add_argument("--parent-pid", type=int, default=None, help=argparse.SUPPRESS)
    add_setting_flags(v)

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
        return _patrol(args_list[1:])
    if args_list[:1] == ["vehicle"] and any(
        a == CENTRAL_FLAG or a.startswith(CENTRAL_FLAG + "=") for a in args_list
    ):
        print(CENTRAL_REFUSAL, file=sys.stderr)
        return 2
    args = _parser().parse_args(args_list)
    try:
        if args.command == "serve":
            return _serve(args, settings_from(args))
        if args.command == "sim" and args.protocol == "mavlink":
            from server.vehicles.mavlink_stack import sim_main

            return sim_main(args)
        if args.command == "sim":
            from drone.sim.server import run_sim

            addr = args.addr or Settings.model_fields["sim_base_addr"].default
            asyncio.run(run_sim(addr, args.world, args.speed))
            return 0
        if args.command == "vehicle":
            from server.vehicles.main import whole_vehicle_main

            return whole_vehicle_main(args, settings_from(args))
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
        print(f"uav-console {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 2


def add_setting_flags(parser: argparse.ArgumentParser) -> None:
    """Every :class:`Settings` field as a flag of ``parser``, grouped by topic in ``--help``.

    ``--kebab-case`` of the field's name (and its aliases); a bool is ``--x/--no-x``, a list
    takes one or more values (the flag may repeat), a Literal its choices; the help is the
    field's description. Each flag defaults to None (given no value: the environment's, else
    the model's default, which is stated once, in the model) and is checked against the field's
    type and bounds as it is parsed, so a bad value is an argparse error naming the flag.
    """
    groups: dict[str, argparse._ArgumentGroup] = {}
    for topic, flags, options in _setting_flags():
        if topic not in groups:
            groups[topic] = parser.add_argument_group(f"settings: {topic}")
        groups[topic].add_argument(*flags, **options)


@functools.cache
def _setting_flags() -> tuple[tuple[str, list[str], dict[str, Any]], ...]:
    """(topic, flags, ``add_argument`` options) of each setting, worked out once a process."""
    out = []
    for name, field in Settings.model_fields.items():
        shape = shape_of(name)
        text = f"{field.description} [{ENV_PREFIX}{name.upper()}; default: {_default(name)}]"
        options: dict[str, Any] = {"dest": name, "default": None, "help": text.replace("%", "%%")}
        if shape.kind is bool:
            options["action"] = argparse.BooleanOptionalAction
        else:
            options["type"] = _value_parser(name, shape)
            options["metavar"] = _METAVARS.get(shape.kind, "TEXT")
            if shape.choices:
                options["choices"] = shape.choices
                options["metavar"] = "{" + ",".join(shape.choices) + "}"
            if shape.many:
                options.update(nargs="+", action="extend")
        flags = [f for f in flags_of(name) if not f.startswith("--no-")]
        out.append((group_of(name), flags, options))
    return tuple(out)


_METAVARS: dict[type, str] = {int: "N", float: "X", Path: "PATH", str: "TEXT"}


def _default(name: str) -> str:
    field = Settings.model_fields[name]
    if field.default_factory is not None:
        return str(field.get_default(call_default_factory=True)).replace(str(Path.home()), "~")
    if field.default is None or field.default == ():
        return "unset"
    if isinstance(field.default, bool):
        return "on" if field.default else "off"
    if isinstance(field.default, tuple):
        return ",".join(str(v) for v in field.default)
    return str(field.default)


def _value_parser(name: str, shape: Shape) -> Callable[[str], Any]:
    """Parse one value of setting ``name`` as its type and bounds (``ge``, ``pattern`` …) say;
    a value they refuse is an :class:`argparse.ArgumentTypeError` (argparse names the flag)."""
    bounds = [] if shape.many else Settings.model_fields[name].metadata
    adapters: list[TypeAdapter[Any]] = []  # built on first use: `interpret` starts quickly

    def parse(text: str) -> Any:
        if not adapters:
            form: Any = Annotated[(shape.kind, *bounds)] if bounds else shape.kind
            adapters.append(TypeAdapter(form))
        try:
            return adapters[0].validate_python(text)
        except ValidationError as exc:
            raise argparse.ArgumentTypeError(f"{text!r}: {exc.errors()[0]['msg']}") from None

    parse.__name__ = shape.kind.__name__  # argparse's "invalid <name> value"
    return parse


def settings_from(args: argparse.Namespace, env: Mapping[str, str] | None = None) -> Settings:
    """The one :class:`Settings` of this process: ``UAVC_*`` variables (the process's, or
    ``env``), then the flags given.

    Raises:
        SettingsError: a value cannot be used; the message names the flags that gave one.
    """
    given: dict[str, Any] = {}
    for name in Settings.model_fields:
        value = getattr(args, name, None)
        if isinstance(value, list):  # a list flag: its values, each maybe comma-separated
            value = tuple(p.strip() for v in value for p in str(v).split(",") if p.strip())
        if value is not None:
            given[name] = value
    try:
        return Settings.from_env(env, **given)
    except SettingsError as exc:
        named = [
            flags_of(n)[0]
            for n in given
            if n in exc.names or re.search(rf"\b{n}\b", str(exc), re.IGNORECASE)
        ]
        raise SettingsError(
            f"{exc} (given as {', '.join(named)})" if named else str(exc), exc.names
        ) from None


def _serve(args: argparse.Namespace, settings: Settings) -> int:
    import uvicorn

    from server.app import create_app
    from server.http.conn_guard import KEEP_ALIVE_S, ConnectionLimits, guarded_h11
    from server.http.ws_guard import preauth_capped_ws
    from server.vehicles.mavlink_stack import drone_kind, is_mavlink

    kinds = [drone_kind(settings.drone, i) for i in range(max(1, settings.fleet))]
    for kind in kinds:  # a bad connection string: refused up front
        is_mavlink(kind)
    if settings.drone != "none":  # simulators on addresses nobody else holds (module simaddr)
        from server.vehicles.simaddr import choose_sim_base

        choice = choose_sim_base(settings, kinds, fixed=args.sim_base_addr is not None)
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
        # before auth, 4 KB: refused at the frame header, unread
        ws=preauth_capped_ws(),
        ssl_certfile=str(tls_files.cert) if tls_files else None,
        ssl_keyfile=str(tls_files.key) if tls_files else None,
        # per-IP connection cap and a header deadline (slowloris)
        http=guarded_h11(ConnectionLimits()),
        timeout_keep_alive=KEEP_ALIVE_S,
        # a faster clock (server/timewarp.py) scales asyncio's selector loop, not uvloop's
        loop="asyncio" if settings.clock_speed != 1.0 else "auto",
    )
    # The pilot's URL is printed when the lifespan has started, which uvicorn does before it
    # binds: the socket listens first, so the printed URL answers the moment it is printed
    # (and a port already taken is refused before any drone starts).
    family = socket.AF_INET6 if ":" in settings.host else socket.AF_INET
    try:
        sock = socket.create_server(
            (settings.host, settings.port), family=family, backlog=config.backlog
        )
    except OSError as exc:
        raise SettingsError(f"cannot listen on {settings.host}:{settings.port}: {exc}") from exc
    # The bus before the first request: the vehicle processes join the console over it, so
    # a router that cannot start stops serve here with one line.
    from server.vehicles.errors import NoBus

    with sock:
        if settings.vehicles == "process":
            try:
                app.state.runtime.vehicles.open_bus(
                    0 if settings.drone == "none" else settings.fleet
                )
            except NoBus as exc:
                raise SettingsError(str(exc)) from exc
        # uvicorn shuts down gracefully on Ctrl-C, then re-raises it: that is a normal exit.
        with contextlib.suppress(KeyboardInterrupt):
            uvicorn.Server(config).run(sockets=[sock])
    return 0


def _patrol(argv: list[str]) -> int:
    """``uav-console patrol``: the experiment is the source checkout's ``experiments/patrol``, no
    part of the installed package; without it, say so (exit status 2)."""
    try:
        from experiments.patrol.cli import patrol_main
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".")[0] != "experiments":
            raise
        if not (ROOT / "experiments" / "patrol" / "__init__.py").is_file():
            print(
                "uav-console patrol: the patrol experiment is not installed; it runs from a "
                "source checkout (experiments/patrol, with pip install -e '.[report]')",
                file=sys.stderr,
            )
            return 2
        sys.path.append(str(ROOT))  # an installed `uav-console` run on a checkout
        from experiments.patrol.cli import patrol_main
    return patrol_main(argv)


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
