"""The bus's user/password dictionary: one random password per user, kept 0600 in the data
directory (``<data dir>/bus/credentials.txt``, Zenoh's ``dictionary_file`` format,
``user:password`` per line)."""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterable, Mapping
from pathlib import Path

from drone.bus.config import (
    CONSOLE_USER,
    OBSERVER_USER,
    PILOT_USER,
    vehicle_user,
    vehicles_among,
)
from drone.bus.errors import BusConfigError

FILE_NAME = "credentials.txt"


class Credentials:
    """Users and passwords of one console's bus."""

    def __init__(self, path: Path, users: dict[str, str]) -> None:
        self.path = path
        self.users = users

    def password(self, user: str) -> str:
        try:
            return self.users[user]
        except KeyError:
            raise BusConfigError(f"no bus credential for {user!r} in {self.path}") from None

    def vehicles(self) -> list[str]:
        """Names of the vehicles that have a credential."""
        return vehicles_among(self.users)

    @classmethod
    def load_or_create(
        cls,
        directory: Path,
        vehicles: Iterable[str],
        vehicle_passwords: Mapping[str, str] | None = None,
        shared: Path | None = None,
        revoked: Iterable[str] = (),
    ) -> Credentials:
        """Read the dictionary, adding the roles and any of ``vehicles`` it lacks.

        ``shared``: another console's dictionary (the consoles of a fleet share one): its
        users and passwords replace this one's. ``vehicle_passwords`` (name → password: the
        console's vehicle keys) are authoritative over both: a vehicle joins the bus with the
        same key it joins the console with. ``revoked``: vehicles whose key was removed, dropped
        unless ``vehicles``, ``vehicle_passwords`` or ``shared`` name them.

        Raises:
            BusConfigError: a line of a file is not ``user:password``, or ``shared`` cannot
                be read.
        """
        directory.mkdir(parents=True, exist_ok=True)
        os.chmod(directory, 0o700)
        path = directory / FILE_NAME
        users = read_dictionary(path) if path.exists() else {}
        before = dict(users)
        shared_users: dict[str, str] = {}
        if shared is not None:
            try:
                shared_users = read_dictionary(shared)
            except OSError as exc:
                raise BusConfigError(f"the shared bus credentials: {exc}") from None
            users.update(shared_users)
        given = {vehicle_user(n): p for n, p in (vehicle_passwords or {}).items()}
        changed = {u for u, p in given.items() if users.get(u) != p}
        users.update(given)
        wanted = [CONSOLE_USER, OBSERVER_USER, PILOT_USER, *(vehicle_user(v) for v in vehicles)]
        keep = set(wanted) | set(given) | set(shared_users)
        gone = {vehicle_user(n) for n in revoked} - keep
        users = {u: p for u, p in users.items() if u not in gone}
        missing = [u for u in wanted if u not in users]
        for user in missing:
            users[user] = secrets.token_urlsafe(24)
        if missing or changed or users != before or not path.exists():
            write_private(path, "".join(f"{u}:{p}\n" for u, p in users.items()))
        return cls(path, users)


def read_dictionary(path: Path) -> dict[str, str]:
    """``user:password`` lines (Zenoh's ``dictionary_file``).

    Raises:
        BusConfigError: a line is not ``user:password``.
        OSError: the file cannot be read.
    """
    users: dict[str, str] = {}
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        user, sep, password = line.partition(":")
        if not sep or not user or not password:
            raise BusConfigError(f"{path}:{n}: not user:password")
        users[user] = password
    return users


def write_private(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` readable by its owner only, atomically."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.replace(tmp, path)
