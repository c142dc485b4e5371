"""``uav-console vehicle-key NAME [NAME …]``: make, show, rotate or revoke vehicles' own keys.

Run on the console's computer (the key goes to ``<data dir>/vehicle-keys/NAME.key``, 0600). It
prints where the key is and the command that starts the vehicle with it; ``--print`` prints the
key alone, for a pipe (``uav-console vehicle-key uav7 --print | ssh drone 'umask 077; cat >
uav7.key'``). ``serve`` makes the keys of the vehicles it spawns itself.
"""

from __future__ import annotations

import argparse
import sys
from typing import TextIO

from server.settings import Settings
from server.vehicles.errors import VehicleKeyError
from server.vehicles.keys import VehicleKeys


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    from pathlib import Path

    k = sub.add_parser(
        "vehicle-key",
        help="make or show a vehicle's own key (what `vehicle --key-file` joins with)",
    )
    k.add_argument("names", nargs="+", metavar="NAME", help="a vehicle's name (uav7: /uav7/...)")
    k.add_argument("--data-dir", type=Path, default=None, help="the console's data directory")
    what = k.add_mutually_exclusive_group()
    what.add_argument("--rotate", action="store_true", help="a new key; the old one stops working")
    what.add_argument("--revoke", action="store_true", help="remove the key")
    k.add_argument(
        "--print", dest="print_key", action="store_true", help="print the key alone (one NAME)"
    )


def vehicle_key_main(
    args: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None
) -> int:
    out = out or sys.stdout  # looked up now: a default bound at import would keep a stale one
    err = err or sys.stderr
    settings = Settings.from_env(data_dir=args.data_dir)
    keys = VehicleKeys(settings.data_dir)
    if args.print_key and len(args.names) != 1:
        print("uav-console vehicle-key: --print takes exactly one NAME", file=err)
        return 2
    try:
        for name in args.names:
            _one(keys, name, args, out)
    except VehicleKeyError as exc:
        print(f"uav-console vehicle-key: {exc}", file=err)
        return 2
    return 0


def _one(keys: VehicleKeys, name: str, args: argparse.Namespace, out: TextIO) -> None:
    if args.revoke:
        if keys.revoke(name):
            print(
                f"{name}'s vehicle key removed: it opens nothing any more (a serve running "
                "on this data directory cuts that vehicle off its bus within a second)",
                file=out,
            )
        else:
            print(f"{name} had no vehicle key", file=out)
        return
    before = keys.get(name)
    key = keys.rotate(name) if args.rotate else keys.ensure(name)
    if args.print_key:
        print(key.secret, file=out)
        return
    how = "rotated" if args.rotate else ("already there" if before is not None else "made now")
    print(f"{key.name}'s vehicle key ({how}): {key.path}", file=out)
    print("  copy it to the vehicle's computer (mode 0600) and run there:", file=out)
    print(
        f"  uav-console vehicle --bus-connect tcp/CONSOLE:7447 "
        f"--name {key.name} --key-file {key.path.name}",
        file=out,
    )
    print(
        "  (the endpoint serve prints as 'bus: …'; tls/ off loopback, with --bus-ca and the "
        "console's tls/ca.pem; a serve running on this data directory lets it on its bus "
        "within a second)",
        file=out,
    )
