"""``uav-console vehicle --central ws://HOST:PORT/vehicle-link --name NAME``: a whole vehicle.

Settings come from ``UAVC_*`` (``serve`` passes all of its own to the vehicles it spawns) and
the flags; the token from ``--token`` or ``UAVC_TOKEN``.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import sys

from server.settings import Settings
from server.vehicles.errors import CannotStart, VehicleError
from server.vehicles.host import VehicleOptions, run_vehicle
from server.vehicles.names import EXIT_CANNOT_START


def whole_vehicle_main(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    token = args.token or os.environ.get("UAVC_TOKEN")
    if not token:
        print(
            "uav-console vehicle: a pilot token is needed (--token or UAVC_TOKEN)", file=sys.stderr
        )
        return 2
    digits = "".join(c for c in args.name if c.isdigit())
    index = args.index if args.index is not None else max(0, int(digits or 1) - 1)
    settings = Settings.from_env(drone=args.drone, world=args.world)
    options = VehicleOptions(
        central=args.central,
        name=args.name,
        prefix=f"/{args.name}" if args.prefix is None else args.prefix.rstrip("/"),
        index=index,
        safety_host=args.safety_host,
        safety_port=args.safety_port,
        safety_cert=args.safety_cert,
        safety_key=args.safety_key,
        parent_pid=args.parent_pid,
        ca_file=args.ca,
        fingerprint=args.fingerprint,
    )
    try:
        asyncio.run(run_vehicle(settings, options, token))
    except CannotStart as exc:  # one line, no traceback: the operator can act on it
        print(f"uav-console vehicle: {exc}", file=sys.stderr)
        return EXIT_CANNOT_START
    except VehicleError as exc:
        print(f"uav-console vehicle: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0
