"""Vehicle keys: each vehicle's own credential to join the console, never the pilot token.

The console keeps one key per vehicle name in ``<data dir>/vehicle-keys/NAME.key`` (the key on
one line, mode 0600, in a 0700 directory). ``serve`` makes the key of each vehicle it spawns
and hands it over in the child's environment (:data:`KEY_ENV`, never on the command line, where
``ps`` shows it). A vehicle on another computer gets its key from the operator:
``uav-console vehicle-key NAME`` makes (or shows) it, and the vehicle reads it with
``uav-console vehicle --key-file PATH`` (or :data:`KEY_ENV`).

Whoever presents a key is that vehicle and nothing more: :meth:`VehicleKeys.vehicle_for` maps a
key to its name (constant-time comparisons), and the bus lets that name publish only under its
own name (docs/bus.md). The store is the console's list of who may join as which vehicle
(bus user ``vehicle-NAME``, password = key).

Reading a key (:func:`read_key_file`, :func:`parse_key`) needs nothing of the web stack, so the
vehicle process can use it without importing it.
"""

from __future__ import annotations

import hmac
import os
import re
import secrets
import stat
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from server.vehicles.errors import VehicleKeyError

KEY_DIR = "vehicle-keys"
KEY_SUFFIX = ".key"
KEY_ENV = "UAVC_VEHICLE_KEY"
# Recognisable at a glance, and never mistaken for a pilot token pasted in its place.
KEY_PREFIX = "uavk_"
# A ROS graph name component (the vehicle's topics are /NAME/...), and a safe file name.
NAME_RE = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,63}$")
KEY_RE = re.compile(r"^uavk_[A-Za-z0-9_-]{32,128}$")
# A key made or removed while the console runs counts within this long (a lookup rescans the
# directory at most this often, so refused guesses cannot make it read the disk any faster).
RESCAN_S = 1.0
# The console's bus looks at the key directory this often (a stat of it and of its files; the
# keys themselves are read only when that changes) ...
WATCH_PERIOD_S = 0.25
# ... and takes a change once the directory has kept still this long, so that one
# `vehicle-key a b c` (three files written in a row) restarts the bus's router once.
WATCH_QUIET_S = 0.5

Signature = tuple[tuple[str, int, int, int], ...]


def check_name(name: str) -> str:
    """``name`` if it can name a vehicle (letters, digits, ``_``; a letter first; ≤ 64).

    Raises:
        VehicleKeyError: it cannot (it would not be a topic name component, or a file name).
    """
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise VehicleKeyError(
            f"bad vehicle name {name!r}: letters, digits and _ only, a letter first, "
            "at most 64 characters (it names the vehicle's topics, /NAME/...)"
        )
    return name


def new_key() -> str:
    """A fresh key: :data:`KEY_PREFIX` and 256 random bits, URL-safe."""
    return KEY_PREFIX + secrets.token_urlsafe(32)


def parse_key(text: str, source: str) -> str:
    """The key in ``text`` (surrounding blanks removed).

    Raises:
        VehicleKeyError: empty, several lines, or not a vehicle key (e.g. a pilot token);
            the message names ``source`` and how to get a key.
    """
    key = text.strip()
    if not key:
        raise VehicleKeyError(f"{source} is empty: {_HOW}")
    if not KEY_RE.match(key):
        what = "several lines" if "\n" in key else "not a vehicle key"
        raise VehicleKeyError(
            f"{source} holds {what} (a vehicle key starts with {KEY_PREFIX!r}; the pilot "
            f"token does not open the bus as a vehicle): {_HOW}"
        )
    return key


def read_key_file(path: Path) -> str:
    """The key in the file at ``path``.

    Raises:
        VehicleKeyError: missing, unreadable, or not holding one key.
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise VehicleKeyError(f"no vehicle key file {path}: {_HOW}") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise VehicleKeyError(f"cannot read the vehicle key file {path}: {exc}") from exc
    return parse_key(text, f"the vehicle key file {path}")


def loosely_readable(path: Path) -> bool:
    """Whether others than the owner may read the file at ``path`` (a key should be 0600)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return bool(mode & (stat.S_IRWXG | stat.S_IRWXO))


_HOW = (
    "make one on the console's computer with `uav-console vehicle-key NAME` and copy the file "
    "it names to the vehicle (mode 0600)"
)


@dataclass(frozen=True)
class VehicleKey:
    """One vehicle's key as stored (``secret`` is kept out of ``repr``)."""

    name: str
    secret: str = field(repr=False)
    path: Path


@dataclass(frozen=True)
class KeyScan:
    """The key directory as read once: every vehicle's key, and each file in it that holds
    no usable key (one line each: the file and why)."""

    keys: Mapping[str, str] = field(repr=False)  # name -> key
    problems: tuple[str, ...] = ()


class KeyWatch:
    """When the console's bus should read the vehicle keys again (sans-I/O: fed the
    directory's :meth:`VehicleKeys.signature` and the time).

    A change is taken once the directory has kept still for ``quiet_s`` (a burst of writes is
    one change); :meth:`observe` says True once per change. The first observation counts as a
    change: the keys the bus started with may have been read before it.
    """

    def __init__(self, quiet_s: float = WATCH_QUIET_S) -> None:
        self.quiet_s = quiet_s
        self._seen: Signature | None = None  # None: nothing observed yet
        self._changed_at: float | None = None

    def observe(self, signature: Signature, now: float) -> bool:
        """Whether to read the keys now."""
        if signature != self._seen:  # the first observation too (a signature is never None)
            self._seen = signature
            self._changed_at = now
            return False
        if self._changed_at is not None and now - self._changed_at >= self.quiet_s:
            self._changed_at = None
            return True
        return False

    def again(self, now: float) -> None:
        """Read the keys again after the quiet time (what was read could not be applied)."""
        self._changed_at = now


class VehicleKeys:
    """The console's key store, one file per vehicle under ``<data_dir>/vehicle-keys``.

    Args:
        data_dir: the console's data directory.
        clock: monotonic seconds, for :data:`RESCAN_S`.
    """

    def __init__(self, data_dir: Path, *, clock: Callable[[], float] = time.monotonic) -> None:
        self.directory = Path(data_dir) / KEY_DIR
        self.clock = clock
        self._secrets: dict[str, str] = {}  # name -> key, as last read from the directory
        self._scanned_at: float | None = None

    def path_of(self, name: str) -> Path:
        return self.directory / f"{check_name(name)}{KEY_SUFFIX}"

    def get(self, name: str) -> VehicleKey | None:
        """``name``'s key, or None when it has none (or its file is not a key).

        Raises:
            VehicleKeyError: ``name`` cannot name a vehicle.
        """
        path = self.path_of(name)
        try:
            secret = read_key_file(path)
        except VehicleKeyError:
            return None
        return VehicleKey(name, secret, path)

    def ensure(self, name: str) -> VehicleKey:
        """``name``'s key, made now if it has none.

        Raises:
            VehicleKeyError: a bad name, or the key cannot be written.
        """
        return self.get(name) or self._write(name)

    def rotate(self, name: str) -> VehicleKey:
        """A new key for ``name``; the old one opens nothing any more (within :data:`RESCAN_S`;
        a connection it already opened stays open until the vehicle reconnects)."""
        return self._write(name)

    def revoke(self, name: str) -> bool:
        """Remove ``name``'s key; whether there was one."""
        path = self.path_of(name)
        try:
            path.unlink()
        except FileNotFoundError:
            return False
        except OSError as exc:
            raise VehicleKeyError(f"cannot remove {path}: {exc}") from exc
        self._scanned_at = None
        return True

    def all(self) -> list[VehicleKey]:
        """Every stored key, by name (the files that hold none left out: :meth:`scan`)."""
        return [VehicleKey(n, k, self.path_of(n)) for n, k in self.scan().keys.items()]

    def signature(self) -> Signature:
        """What the directory looks like (each file's name, size, inode and change time, and
        the directory's own): cheap to take often; it changes when a key is made, replaced
        or removed, by this module or by hand."""
        try:
            st = os.stat(self.directory)
            entries = list(os.scandir(self.directory))
        except OSError:
            return ()
        found = [("", st.st_mtime_ns, st.st_ino, 0)]
        for entry in entries:
            if entry.name.endswith(KEY_SUFFIX):
                try:
                    est = entry.stat(follow_symlinks=True)
                except OSError:
                    found.append((entry.name, -1, -1, -1))
                    continue
                found.append((entry.name, est.st_mtime_ns, est.st_ino, est.st_size))
        return tuple(sorted(found))

    def scan(self) -> KeyScan:
        """Every key in the directory, and each ``*.key`` file that holds none (a bad name, not
        a key, unreadable), said in a line."""
        found: dict[str, str] = {}
        problems: list[str] = []
        try:
            paths = sorted(self.directory.glob(f"*{KEY_SUFFIX}"))
        except OSError as exc:
            return KeyScan({}, (f"cannot read the vehicle key directory {self.directory}: {exc}",))
        for path in paths:
            name = path.name[: -len(KEY_SUFFIX)]
            if not NAME_RE.match(name):
                problems.append(
                    f"{path}: {name!r} cannot name a vehicle (letters, digits and _ only, a "
                    "letter first)"
                )
                continue
            try:
                found[name] = read_key_file(path)
            except VehicleKeyError as exc:
                if path.exists():  # else removed since the listing: not a problem
                    problems.append(str(exc))
        return KeyScan(found, tuple(problems))

    def vehicle_for(self, key: str | None) -> str | None:
        """The vehicle ``key`` belongs to, or None. Every stored key is compared, in constant
        time each, so the answer's timing tells nothing of which one came close."""
        if not key or not isinstance(key, str):
            return None
        now = self.clock()
        if self._scanned_at is None or now - self._scanned_at >= RESCAN_S:
            self._secrets = {k.name: k.secret for k in self.all()}
            self._scanned_at = now
        raw = key.encode("utf-8", "surrogatepass")
        found = None
        for name, secret in self._secrets.items():
            if hmac.compare_digest(raw, secret.encode()):
                found = name
        return found

    def _write(self, name: str) -> VehicleKey:
        # Lazily: the vehicle process reads keys and must not import the web stack for that.
        from server.http.security import secure_dir, write_private_atomically

        path = self.path_of(name)
        key = new_key()
        try:
            secure_dir(self.directory)
            write_private_atomically(path, key + "\n")
        except OSError as exc:
            raise VehicleKeyError(f"cannot write the vehicle key {path}: {exc}") from exc
        self._scanned_at = None
        return VehicleKey(name, key, path)


def key_from(key_file: Path | None, env: Mapping[str, str]) -> str:
    """The vehicle's own key: ``--key-file`` if given, else :data:`KEY_ENV`.

    Raises:
        VehicleKeyError: neither is given, or what is given is not a key.
    """
    if key_file is not None:
        return read_key_file(key_file)
    value = env.get(KEY_ENV)
    if value is None:
        raise VehicleKeyError(f"a vehicle key is needed (--key-file PATH or {KEY_ENV}): {_HOW}")
    return parse_key(value, KEY_ENV)


def vehicle_env(env: Mapping[str, str], keys: VehicleKeys, name: str) -> dict[str, str]:
    """``env`` for the vehicle ``name`` that ``serve`` spawns: plus its own key (made now if it
    has none) as :data:`KEY_ENV`, where ``ps`` does not show it.

    Raises:
        VehicleKeyError: a bad name, or the key cannot be written.
    """
    return {**env, KEY_ENV: keys.ensure(name).secret}


__all__ = [
    "KEY_ENV",
    "KeyScan",
    "KeyWatch",
    "VehicleKey",
    "VehicleKeys",
    "check_name",
    "key_from",
    "new_key",
    "parse_key",
    "read_key_file",
    "vehicle_env",
]
