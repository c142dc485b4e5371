"""``uav-console replay FILE.mcap [--speed S]``: load, check, serve (see ``replay_app``)."""

from __future__ import annotations

import argparse
import contextlib
import secrets
import sys

from server.recorder.errors import CorruptRecording


def replay_main(args: argparse.Namespace) -> int:
    """Serve the console on a recording; 2 with a clear message for a bad file or speed."""
    import uvicorn

    from server.recorder.replay import flight_start_ns, load
    from server.recorder.replay_app import create_replay_app
    from server.settings import Settings

    if not args.speed > 0:
        print(f"uav-console replay: --speed must be positive, not {args.speed}", file=sys.stderr)
        return 2
    try:
        recording, played = load(args.file, recover=args.recover)
    except CorruptRecording as exc:
        hint = ""
        if not args.recover and "truncated" in exc.why:
            hint = " (a flight cut short by a crash: --recover plays what was written)"
        print(f"uav-console replay: {exc}{hint}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"uav-console replay: cannot read {args.file}: {exc}", file=sys.stderr)
        return 2
    if not played:
        print(f"uav-console replay: {args.file} holds no messages", file=sys.stderr)
        return 2
    # Read-only: the page gets the observer token; the pilot token is random and not shown.
    token = args.token or secrets.token_urlsafe(16)
    settings = Settings.from_env(
        host=args.host, port=args.port, observer_token=token, token=secrets.token_urlsafe(24)
    )
    app = create_replay_app(args.file, recording, played, speed=args.speed, settings=settings)
    if args.paused:
        app.state.start_paused = True
    start = max(played[0].t_ns, flight_start_ns(recording) or played[0].t_ns)
    timeline = played[-1].t_ns - min(start, played[-1].t_ns)
    print(
        f"replaying {args.file} ({len(played)} messages, {timeline / 1e9:.1f} s, "
        f"{len(recording.channels)} topics) at {args.speed:g}×",
        file=sys.stderr,
    )
    print(f"http://{settings.host}:{settings.port}/?token={token}", flush=True)
    from server.http.ws_guard import preauth_capped_ws

    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level="warning",
        ws=preauth_capped_ws(),  # frames over 4 KB before auth refused at the header
    )
    with contextlib.suppress(KeyboardInterrupt):
        uvicorn.Server(config).run()
    return 0
