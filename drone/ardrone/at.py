"""Sans-I/O codec for AR.Drone 2.0 AT commands (UDP 5556).

Wire form (Developer Guide SDK 2.0 §6.1): ``AT*NAME=<seq>[,arg]*\\r``; several commands may
share one datagram of at most 1024 bytes (§6.1 "maximum length"). Integers are decimal; floats are
sent as the signed decimal int32 of their IEEE-754 single-precision bits
(§6.2: −0.8 → ``-1085485875``);
strings are double-quoted and may not contain a quote or a line break.

The client side uses :class:`ATEncoder` (it owns the sequence number); the simulator side uses
:func:`parse_at`. Neither opens a socket nor reads a clock.
"""

from __future__ import annotations

import math
import re
import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import ClassVar

from drone.ardrone.errors import ATEncodeError, ATParseError

MAX_DATAGRAM = 1024  # Developer Guide §6.1: total length of an AT datagram
MAX_SEQ = 2**31 - 1  # sequence numbers are signed int32 on the drone

# AT*REF bits (Developer Guide §6.6, ARDroneLib Soft/Common/ardrone_api.h).
REF_BASE = (1 << 18) | (1 << 20) | (1 << 22) | (1 << 24) | (1 << 28)  # 0x11540000, always set
REF_EMERGENCY_BIT = 1 << 8  # "select": toggles emergency / resets it
REF_TAKEOFF_BIT = 1 << 9  # "start": 1 = take off, 0 = land

# AT*PCMD flag bits (Developer Guide §6.6, ardrone_api.h ARDRONE_PROGRESSIVE_CMD_*).
PCMD_PROGRESSIVE = 1 << 0  # 0 = hover, arguments ignored
PCMD_COMBINED_YAW = 1 << 1
PCMD_ABSOLUTE = 1 << 2

# AT*CTRL modes (ARDroneLib Soft/Common/control_states.h ARDRONE_CONTROL_MODE).
CTRL_NO_CONTROL = 0
CTRL_ARDRONE_UPDATE = 1
CTRL_PIC_UPDATE = 2
CTRL_LOGS_GET = 3
CTRL_CFG_GET = 4
CTRL_ACK = 5  # reset the command-ACK bit in navdata
CTRL_CUSTOM_CFG_GET = 6


def float_to_int(value: float) -> int:
    """The signed int32 whose bits are ``value`` as an IEEE-754 float32 (Developer Guide §6.2).

    Raises:
        ATEncodeError: ``value`` is NaN or infinite (the drone would read garbage).
    """
    if not math.isfinite(value):
        raise ATEncodeError(f"float argument must be finite, got {value!r}")
    try:
        packed = struct.pack("<f", value)
    except OverflowError as exc:  # beyond float32 range
        raise ATEncodeError(f"float argument {value!r} does not fit a float32") from exc
    return int(struct.unpack("<i", packed)[0])


def int_to_float(value: int) -> float:
    """Inverse of :func:`float_to_int`: the float32 whose bits are the int32 ``value``."""
    if not -(2**31) <= value < 2**31:
        raise ATParseError(f"float argument {value} is not an int32")
    return float(struct.unpack("<f", struct.pack("<i", value))[0])


def _int32(name: str, value: int) -> str:
    if not -(2**31) <= value < 2**31:
        raise ATEncodeError(f"{name}={value} is not an int32")
    return str(int(value))


def _string(name: str, value: str) -> str:
    if any(c in value for c in '"\r\n') or not value.isascii():
        raise ATEncodeError(f"{name}={value!r}: AT strings must be ASCII without quotes or CR/LF")
    return f'"{value}"'


@dataclass(frozen=True)
class Ref:
    """``AT*REF``: take-off / land / emergency bitfield (§6.6). Build with the classmethods."""

    NAME: ClassVar[str] = "REF"
    input: int = REF_BASE

    @classmethod
    def takeoff(cls) -> Ref:
        return cls(REF_BASE | REF_TAKEOFF_BIT)

    @classmethod
    def land(cls) -> Ref:
        return cls(REF_BASE)

    @classmethod
    def emergency(cls) -> Ref:
        """Toggle emergency: cuts the motors if flying, clears the emergency state if in it."""
        return cls(REF_BASE | REF_EMERGENCY_BIT)

    @property
    def takeoff_bit(self) -> bool:
        return bool(self.input & REF_TAKEOFF_BIT)

    @property
    def emergency_bit(self) -> bool:
        return bool(self.input & REF_EMERGENCY_BIT)

    def args(self) -> list[str]:
        return [_int32("input", self.input)]


@dataclass(frozen=True)
class Pcmd:
    """``AT*PCMD``: progressive command; fractions of euler_angle_max/control_vz_max/control_yaw."""

    NAME: ClassVar[str] = "PCMD"
    flag: int = 0
    roll: float = 0.0
    pitch: float = 0.0
    gaz: float = 0.0
    yaw: float = 0.0

    @classmethod
    def hover(cls) -> Pcmd:
        return cls(0, 0.0, 0.0, 0.0, 0.0)

    @property
    def progressive(self) -> bool:
        return bool(self.flag & PCMD_PROGRESSIVE)

    def args(self) -> list[str]:
        return [
            _int32("flag", self.flag),
            *(str(float_to_int(v)) for v in (self.roll, self.pitch, self.gaz, self.yaw)),
        ]


@dataclass(frozen=True)
class PcmdMag:
    """``AT*PCMD_MAG``: PCMD plus magnetometer psi and its accuracy (SDK 2.0 §6.6)."""

    NAME: ClassVar[str] = "PCMD_MAG"
    flag: int = 0
    roll: float = 0.0
    pitch: float = 0.0
    gaz: float = 0.0
    yaw: float = 0.0
    psi: float = 0.0
    psi_accuracy: float = 0.0

    @property
    def progressive(self) -> bool:
        return bool(self.flag & PCMD_PROGRESSIVE)

    def args(self) -> list[str]:
        floats = (self.roll, self.pitch, self.gaz, self.yaw, self.psi, self.psi_accuracy)
        return [_int32("flag", self.flag), *(str(float_to_int(v)) for v in floats)]


@dataclass(frozen=True)
class Ftrim:
    """``AT*FTRIM``: flat trim — tells the drone it lies horizontally (only when landed)."""

    NAME: ClassVar[str] = "FTRIM"

    def args(self) -> list[str]:
        return []


@dataclass(frozen=True)
class Config:
    """``AT*CONFIG``: write one configuration key (e.g. ``general:navdata_demo`` = ``TRUE``)."""

    NAME: ClassVar[str] = "CONFIG"
    key: str
    value: str

    def args(self) -> list[str]:
        return [_string("key", self.key), _string("value", self.value)]


@dataclass(frozen=True)
class ConfigIds:
    """``AT*CONFIG_IDS``: session/user/application ids that precede a multiconfig CONFIG."""

    NAME: ClassVar[str] = "CONFIG_IDS"
    session: str
    user: str
    application: str

    def args(self) -> list[str]:
        return [
            _string("session", self.session),
            _string("user", self.user),
            _string("application", self.application),
        ]


@dataclass(frozen=True)
class Comwdg:
    """``AT*COMWDG``: reset the communication watchdog (answer to state bit 30)."""

    NAME: ClassVar[str] = "COMWDG"

    def args(self) -> list[str]:
        return []


@dataclass(frozen=True)
class Ctrl:
    """``AT*CTRL=seq,mode,0``: control mode; mode 5 acknowledges a command (clears ACK bit 6)."""

    NAME: ClassVar[str] = "CTRL"
    mode: int
    arg: int = 0

    def args(self) -> list[str]:
        return [_int32("mode", self.mode), _int32("arg", self.arg)]


@dataclass(frozen=True)
class Calib:
    """``AT*CALIB=seq,device``: calibrate a sensor (0 = magnetometer), only while flying."""

    NAME: ClassVar[str] = "CALIB"
    device: int = 0

    def args(self) -> list[str]:
        return [_int32("device", self.device)]


@dataclass(frozen=True)
class Led:
    """``AT*LED=seq,animation,float(frequency_hz),duration_s`` (SDK 1.x; kept by SDK 2.0)."""

    NAME: ClassVar[str] = "LED"
    animation: int
    frequency_hz: float
    duration_s: int

    def args(self) -> list[str]:
        return [
            _int32("animation", self.animation),
            str(float_to_int(self.frequency_hz)),
            _int32("duration_s", self.duration_s),
        ]


@dataclass(frozen=True)
class Anim:
    """``AT*ANIM=seq,animation,duration_s``: flight animation (SDK 1.x; kept by SDK 2.0)."""

    NAME: ClassVar[str] = "ANIM"
    animation: int
    duration_s: int

    def args(self) -> list[str]:
        return [_int32("animation", self.animation), _int32("duration_s", self.duration_s)]


@dataclass(frozen=True)
class Unknown:
    """A syntactically valid command with a name this codec does not know (the drone ignores it)."""

    name: str
    raw_args: tuple[str, ...] = ()

    @property
    def NAME(self) -> str:
        return self.name

    def args(self) -> list[str]:
        return list(self.raw_args)


ATCommand = Ref | Pcmd | PcmdMag | Ftrim | Config | ConfigIds | Comwdg | Ctrl | Calib | Led | Anim
ParsedCommand = ATCommand | Unknown


@dataclass(frozen=True)
class ATPacket:
    """One parsed command with its sequence number."""

    seq: int
    command: ParsedCommand


def encode_command(command: ATCommand, seq: int) -> bytes:
    """``AT*NAME=seq,args\\r`` as bytes.

    Raises:
        ATEncodeError: an argument cannot be encoded, or ``seq`` is outside 1..2**31-1.
    """
    if not 1 <= seq <= MAX_SEQ:
        raise ATEncodeError(f"sequence number {seq} outside 1..{MAX_SEQ}")
    args = command.args()
    tail = "," + ",".join(args) if args else ""
    return f"AT*{command.NAME}={seq}{tail}\r".encode("ascii")


class ATEncoder:
    """Owns the sequence number and packs commands into datagrams of at most 1024 bytes.

    The first command gets sequence 1 (§6.1: the drone resets its counter on seq 1).
    """

    def __init__(self, first_seq: int = 1, max_datagram: int = MAX_DATAGRAM) -> None:
        self._seq = first_seq
        self.max_datagram = max_datagram

    @property
    def next_seq(self) -> int:
        """The sequence number the next command will carry."""
        return self._seq

    def reset(self, first_seq: int = 1) -> None:
        """Restart numbering (after a reconnection the drone accepts seq 1 as a reset)."""
        self._seq = first_seq

    def encode(self, command: ATCommand) -> bytes:
        """Encode one command with the next sequence number."""
        out = encode_command(command, self._seq)
        self._seq = 1 if self._seq >= MAX_SEQ else self._seq + 1
        return out

    def pack(self, commands: Iterable[ATCommand]) -> list[bytes]:
        """Encode ``commands`` in order into as few datagrams as fit ``max_datagram`` bytes each.

        Raises:
            ATEncodeError: one command alone is longer than ``max_datagram``.
        """
        datagrams: list[bytes] = []
        current = b""
        for command in commands:
            wire = self.encode(command)
            if len(wire) > self.max_datagram:
                raise ATEncodeError(
                    f"AT*{command.NAME} is {len(wire)} bytes, over the datagram limit"
                )
            if len(current) + len(wire) > self.max_datagram:
                datagrams.append(current)
                current = b""
            current += wire
        if current:
            datagrams.append(current)
        return datagrams


_COMMAND_RE = re.compile(rb"AT\*([A-Z_]+)=(\d+)((?:,(?:-?\d+|\"[^\"\r\n]*\"))*)\Z")
_ARG_RE = re.compile(rb'-?\d+|"[^"\r\n]*"')


def _parse_args(raw: bytes) -> list[str]:
    # A quoted string may hold any byte but CR, LF and '"'; the protocol is ASCII (a
    # non-ASCII byte in a CONFIG value is refused here, not a UnicodeDecodeError later).
    if not raw.isascii():
        raise ATParseError(f"non-ASCII bytes in AT arguments {raw[:60]!r}")
    return [m.group(0).decode("ascii") for m in _ARG_RE.finditer(raw)]


def _as_int(name: str, tok: str) -> int:
    if tok.startswith('"'):
        raise ATParseError(f"AT*{name}: expected an integer, got {tok}")
    value = int(tok)
    if not -(2**31) <= value < 2**31:
        raise ATParseError(f"AT*{name}: integer {tok} is not an int32")
    return value


def _as_float(name: str, tok: str) -> float:
    return int_to_float(_as_int(name, tok))


def _as_str(name: str, tok: str) -> str:
    if not tok.startswith('"'):
        raise ATParseError(f"AT*{name}: expected a quoted string, got {tok}")
    return tok[1:-1]


# name -> (arity, builder from the argument tokens)
_BUILDERS: dict[str, tuple[int, object]] = {
    "REF": (1, lambda a: Ref(_as_int("REF", a[0]))),
    "PCMD": (5, lambda a: Pcmd(_as_int("PCMD", a[0]), *(_as_float("PCMD", t) for t in a[1:]))),
    "PCMD_MAG": (
        7,
        lambda a: PcmdMag(_as_int("PCMD_MAG", a[0]), *(_as_float("PCMD_MAG", t) for t in a[1:])),
    ),
    "FTRIM": (0, lambda a: Ftrim()),
    "CONFIG": (2, lambda a: Config(_as_str("CONFIG", a[0]), _as_str("CONFIG", a[1]))),
    "CONFIG_IDS": (3, lambda a: ConfigIds(*(_as_str("CONFIG_IDS", t) for t in a))),
    "COMWDG": (0, lambda a: Comwdg()),
    "CTRL": (2, lambda a: Ctrl(_as_int("CTRL", a[0]), _as_int("CTRL", a[1]))),
    "CALIB": (1, lambda a: Calib(_as_int("CALIB", a[0]))),
    "LED": (3, lambda a: Led(_as_int("LED", a[0]), _as_float("LED", a[1]), _as_int("LED", a[2]))),
    "ANIM": (2, lambda a: Anim(_as_int("ANIM", a[0]), _as_int("ANIM", a[1]))),
}


def parse_at(data: bytes) -> list[ATPacket]:
    """Parse one AT datagram into its commands, in order.

    Every command must be ``AT*NAME=seq[,int|"string"]*`` terminated by ``\\r``; a trailing
    ``\\n`` after the ``\\r`` is tolerated (some clients send CRLF). Unknown names parse as
    :class:`Unknown` (the drone ignores them).

    Raises:
        ATParseError: the datagram is empty, longer than 1024 bytes, not ASCII, not terminated,
            has a malformed command, an argument of the wrong kind or count, or seq < 1.
    """
    if not data:
        raise ATParseError("empty AT datagram")
    if len(data) > MAX_DATAGRAM:
        raise ATParseError(f"AT datagram of {len(data)} bytes exceeds {MAX_DATAGRAM}")
    if not data.endswith((b"\r", b"\r\n")):
        raise ATParseError("AT datagram does not end with CR")
    packets: list[ATPacket] = []
    for chunk in data.split(b"\r")[:-1]:
        chunk = chunk.removeprefix(b"\n")
        match = _COMMAND_RE.match(chunk)
        if match is None:
            raise ATParseError(f"malformed AT command {chunk[:60]!r}")
        name = match.group(1).decode("ascii")
        seq = int(match.group(2))
        if not 1 <= seq <= MAX_SEQ:
            raise ATParseError(f"AT*{name}: sequence number {seq} outside 1..{MAX_SEQ}")
        args = _parse_args(match.group(3))
        spec = _BUILDERS.get(name)
        if spec is None:
            packets.append(ATPacket(seq, Unknown(name, tuple(args))))
            continue
        arity, build = spec
        if len(args) != arity:
            raise ATParseError(f"AT*{name} takes {arity} arguments, got {len(args)}")
        packets.append(ATPacket(seq, build(args)))  # type: ignore[operator]
    return packets


def encode_many(commands: Sequence[tuple[ATCommand, int]]) -> bytes:
    """Concatenate ``(command, seq)`` pairs into one datagram body (tests and golden strings)."""
    return b"".join(encode_command(c, s) for c, s in commands)
