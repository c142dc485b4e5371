"""``uav-console vehicle --bus-connect ENDPOINT --name NAME``: a whole vehicle.

Settings come from ``UAVC_*`` (``serve`` passes all of its own to the vehicles it spawns) and
the flags. It joins the bus with the vehicle's own key: ``--key-file PATH`` or ``UAVC_VEHICLE_KEY``
(``serve`` puts it there for the vehicles it spawns; for a vehicle on another computer the
console's operator makes it with ``uav-console vehicle-key NAME``). The pilot token
(``--token`` or ``UAVC_TOKEN``) and the safety door's ticket secret ``UAVC_DOOR_SECRET`` (hex;
``serve`` gives each vehicle it spawns its own) let pages open the vehicle's safety door;
without either the door refuses everyone.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import sys

from server.settings import Settings
from server.vehicles.errors import CannotStart, VehicleError, VehicleKeyError
from server.vehicles.host import VehicleOptions, run_vehicle
from server.vehicles.keys import check_name, key_from, loosely_readable
from server.vehicles.names import EXIT_CANNOT_START

log = logging.getLogger("uav_console.vehicle")


def whole_vehicle_main(args: argparse.Namespace, settings: Settings) -> int:
    """Run the vehicle: ``args`` its own flags, ``settings`` read once by the command."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    if not settings.bus_connect:
        print("uav-console vehicle: --bus-connect ENDPOINT is needed", file=sys.stderr)
        return 2
    try:
        check_name(args.name)
        key = key_from(args.key_file, os.environ)
    except VehicleKeyError as exc:
        print(f"uav-console vehicle: {exc}", file=sys.stderr)
        return 2
    if args.key_file is not None and loosely_readable(args.key_file):
        log.warning("%s: others may read the vehicle key file (chmod 600 it)", args.key_file)
    safety_token = settings.token
    if not safety_token:
        log.warning(
            "no pilot token (--token or UAVC_TOKEN): the safety door takes console tickets only"
        )
    digits = "".join(c for c in args.name if c.isdigit())
    index = args.index if args.index is not None else max(0, int(digits or 1) - 1)
    secret_hex = os.environ.get("UAVC_DOOR_SECRET", "")
    try:
        door_secret = bytes.fromhex(secret_hex) if secret_hex else None
    except ValueError:
        print("uav-console vehicle: UAVC_DOOR_SECRET is not hex", file=sys.stderr)
        return 2
    options = VehicleOptions(
        name=args.name,
        prefix=f"/{args.name}" if args.prefix is None else args.prefix.rstrip("/"),
        index=index,
        safety_host=args.safety_host,
        safety_port=args.safety_port,
        safety_cert=args.safety_cert,
        safety_key=args.safety_key,
        door_secret=door_secret,
        parent_pid=args.parent_pid,
    )
    try:
        asyncio.run(run_vehicle(settings, options, key, safety_token=safety_token))
    except CannotStart as exc:  # one line, no traceback: the operator can act on it
        print(f"uav-console vehicle: {exc}", file=sys.stderr)
        return EXIT_CANNOT_START
    except VehicleError as exc:
        print(f"uav-console vehicle: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0
