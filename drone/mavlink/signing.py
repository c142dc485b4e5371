"""The MAVLink 2 signing key of the simulator and the console: a passphrase in a private file.

Ground stations take a signing key as a passphrase and use its SHA-256 as the 32-byte secret:
MAVProxy (``signing setup``/``signing key PASSPHRASE``, ``mavproxy_signing.py``
``passphrase_to_key``), Mission Planner and QGroundControl alike. So the file holds a
passphrase (43 URL-safe characters from 32 random bytes) and the key is its SHA-256: one file
that every ground station, pymavlink and this console can be given.

The file lives at ``<data dir>/mavlink/signing-passphrase``, mode 0600 in a 0700 directory; it
is made once, atomically (several vehicle processes of one ``serve`` may start together: the
first one's file is the one all of them read). A file that others may read, or that holds no
usable passphrase, is refused with :class:`~drone.mavlink.errors.SigningKeyError`.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import secrets
import stat
from pathlib import Path

from drone.mavlink.errors import SigningKeyError

KEY_DIR = "mavlink"
KEY_FILE = "signing-passphrase"
MIN_PASSPHRASE = 8  # characters; a generated one has 43


def key_path(data_dir: Path) -> Path:
    """Where the passphrase of ``data_dir`` lives."""
    return data_dir / KEY_DIR / KEY_FILE


def key_from_passphrase(passphrase: str) -> bytes:
    """The 32-byte signing secret of ``passphrase``: its SHA-256, as MAVProxy derives it.

    Raises:
        SigningKeyError: not printable ASCII of at least 8 characters.
    """
    text = passphrase.strip()
    if len(text) < MIN_PASSPHRASE or not text.isascii() or not text.isprintable():
        raise SigningKeyError(
            f"a signing passphrase is at least {MIN_PASSPHRASE} printable ASCII characters"
        )
    return hashlib.sha256(text.encode("ascii")).digest()


def read_passphrase(path: Path) -> str:
    """The passphrase in ``path``.

    Raises:
        SigningKeyError: unreadable, readable by others, or not a passphrase.
    """
    try:
        mode = path.stat().st_mode
        text = path.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as exc:
        raise SigningKeyError(f"cannot read the MAVLink signing passphrase {path}: {exc}") from exc
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SigningKeyError(
            f"{path} may be read by others (mode {stat.S_IMODE(mode):04o}): chmod 600 it"
        )
    key_from_passphrase(text)  # validates
    return text.strip()


def load_or_create(data_dir: Path) -> tuple[bytes, Path]:
    """The signing key of ``data_dir`` (made on first use) and the file it comes from.

    Raises:
        SigningKeyError: the file cannot be made or read, or is not private.
    """
    path = key_path(data_dir)
    if not path.exists():
        _create(path)
    return key_from_passphrase(read_passphrase(path)), path


def _create(path: Path) -> None:
    """Write a new passphrase to ``path`` unless another process got there first."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        os.chmod(path.parent, 0o700)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            with os.fdopen(fd, "w", encoding="ascii") as fh:
                fh.write(secrets.token_urlsafe(32) + "\n")
                fh.flush()
                os.fsync(fh.fileno())
            with contextlib.suppress(FileExistsError):
                os.link(tmp, path)  # never replaces a file another process made meanwhile
        finally:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    except OSError as exc:
        raise SigningKeyError(f"cannot create the signing passphrase {path}: {exc}") from exc
