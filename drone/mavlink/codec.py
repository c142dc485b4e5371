"""Sans-I/O MAVLink 2 framing on pymavlink: bytes in → typed messages, messages → bytes.

One :class:`Codec` per link end (per TCP connection, per UDP peer). It owns pymavlink's parser
and its outgoing sequence counter, no socket and no clock. Frames that are not acceptable are
counted by reason in ``rejected`` and never raise:

* ``garbage`` — bytes that are no frame at all (pymavlink's ``MAVLink_bad_data``), including
  frames whose CRC does not match (``bad_crc``, told apart by pymavlink's reason text);
* ``mavlink1`` — a MAVLink 1 frame (magic 0xFE): this console speaks MAVLink 2 only, as PX4
  and ArduPilot do on any link after the first MAVLink 2 frame (MAVLink docs "MAVLink 2 —
  Version handshaking");
* ``bad_signature`` — a signed link (``signing_key``) got a frame with a wrong or missing
  signature, or a replayed one (MAVLink docs "Message Signing": the SHA-256 signature, then
  the timestamp against the last one of its (link id, system, component) stream). The
  signature is checked *first*, as the MAVLink C library's ``mavlink_signature_check`` does:
  pymavlink 2.4.50 stores a frame's timestamp before it looks at the signature, so one forged
  frame with a far-future timestamp made every genuine frame after it "old" and silenced a
  signed link for good (:func:`_check_signature` replaces its check).

A vehicle with several links shares one signing state among their codecs
(:func:`signing_state`): one outgoing timestamp and one table of stream timestamps, as
ArduPilot's ``GCS_Signing`` keeps them, so a frame captured on one link and replayed on another
(a new TCP connection) is as old there as on its own link.

Signing timestamps count 10 µs since 2015-01-01 00:00 UTC (MAVLink docs "Message Signing",
Timestamp): :func:`signing_timestamp` turns a Unix time into one; a link end keeps its own at
least at its wall clock (:meth:`Codec.keep_up`), as MAVProxy's signing module does, so a peer
that checks "a new stream at most one minute behind" hears it.

The dialect is ArduPilot's ``ardupilotmega`` (a superset of ``common``), so an ArduPilot
vehicle's own messages decode too.
"""

from __future__ import annotations

import collections
import hashlib
import hmac
import struct
from collections.abc import Callable
from typing import Any, TypeAlias

from pymavlink.dialects.v20 import ardupilotmega as mav

__all__ = ["MAGIC_V2", "Codec", "Message", "mav", "signing_state", "signing_timestamp"]

# pymavlink ships no type information: a decoded message is typed Any here.
Message: TypeAlias = Any
MAGIC_V2 = 0xFD  # MAVLink 2 start-of-frame (mavlink.io "Packet Serialization")
NEW_STREAM_WINDOW = 6_000_000  # 60 s in 10 µs units: how far behind a new stream may start
_TIMESTAMP = struct.Struct("<IH")  # the signature block's 48-bit timestamp
SIGNING_EPOCH_UNIX_S = 1420070400  # 2015-01-01 00:00:00 UTC (MAVLink docs "Message Signing")


def signing_timestamp(unix_s: float) -> int:
    """A Unix time as a MAVLink 2 signing timestamp (10 µs units since 2015-01-01 UTC)."""
    return max(0, int((unix_s - SIGNING_EPOCH_UNIX_S) * 100_000))


def signing_state(
    key: bytes,
    *,
    link_id: int = 0,
    timestamp: int = 0,
    accept_unsigned: Callable[[int], bool] | None = None,
) -> Any:
    """A signing state (pymavlink ``MAVLinkSigning``) for one or several codecs to share.

    Args:
        key: the 32-byte secret.
        link_id: the link id put in what is sent.
        timestamp: the first outgoing timestamp (:func:`signing_timestamp`).
        accept_unsigned: unsigned frames still accepted, by message id; default none.

    Raises:
        ValueError: the key is not 32 bytes.
    """
    if len(key) != 32:
        raise ValueError("a MAVLink 2 signing key is 32 bytes")
    state = mav.MAVLinkSigning()
    state.secret_key = bytes(key)
    state.link_id = link_id
    state.sign_outgoing = True
    state.timestamp = timestamp

    def _allow(_mav: Any, msg_id: int) -> bool:
        return bool(accept_unsigned(msg_id)) if accept_unsigned is not None else False

    state.allow_unsigned_callback = _allow
    return state


def _check_signature(signing: Any, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
    """Whether a signed frame is genuine and new: the signature first, then the timestamp,
    and only a genuine frame moves its stream's timestamp (MAVLink C library,
    ``mavlink_signature_check``; see the module docstring)."""
    digest = hashlib.sha256(signing.secret_key + bytes(msgbuf[:-6])).digest()[:6]
    if not hmac.compare_digest(digest, bytes(msgbuf[-6:])):
        return False
    low, high = _TIMESTAMP.unpack(bytes(msgbuf[-12:-6]))
    timestamp = low + (high << 32)
    stream = (msgbuf[-13], src_system, src_component)  # (link id, system, component)
    last = signing.stream_timestamps.get(stream)
    if last is not None and timestamp <= last:
        return False  # a replay, or older than what this stream already sent
    if last is None and timestamp + NEW_STREAM_WINDOW < signing.timestamp:
        return False  # a new stream starting more than a minute in the past
    signing.stream_timestamps[stream] = timestamp
    signing.timestamp = max(signing.timestamp, timestamp)
    return True


class Codec:
    """See the module docstring.

    Args:
        system_id: our own system id (a GCS uses 255, the sim autopilot 1).
        component_id: our component (MAV_COMP_ID_MISSIONPLANNER 190 for a GCS, 1 for an autopilot).
        signing_key: 32-byte secret: sign everything we send and accept only signed frames.
        link_id: the signing link id (one per link end).
        accept_unsigned: with a key, still accept unsigned frames for which this returns True
            (by message id); default: none.
        initial_timestamp: with a key, the first outgoing signing timestamp (default 0).
        signing: a :func:`signing_state` shared with other codecs (instead of ``signing_key``).
    """

    def __init__(
        self,
        system_id: int,
        component_id: int,
        *,
        signing_key: bytes | None = None,
        link_id: int = 0,
        accept_unsigned: Callable[[int], bool] | None = None,
        initial_timestamp: int | None = None,
        signing: Any | None = None,
    ) -> None:
        self.mav = mav.MAVLink(None, system_id, component_id)
        self.mav.robust_parsing = True
        self.rejected: collections.Counter[str] = collections.Counter()
        self.accepted = 0
        self.bytes_in = 0
        if signing is None and signing_key is not None:
            signing = signing_state(
                signing_key,
                link_id=link_id,
                timestamp=initial_timestamp or 0,
                accept_unsigned=accept_unsigned,
            )
        self.signed = signing is not None
        if signing is not None:
            self.mav.signing = signing
            state = signing

            def _check(msgbuf: bytearray, src_system: int, src_component: int) -> bool:
                return _check_signature(state, msgbuf, src_system, src_component)

            self.mav.check_signature = _check

    def keep_up(self, timestamp: int) -> None:
        """Keep the outgoing signing timestamp at least ``timestamp`` (:func:`signing_timestamp`
        of the wall clock); nothing on an unsigned codec."""
        if self.signed and timestamp > self.mav.signing.timestamp:
            self.mav.signing.timestamp = timestamp

    def feed(self, data: bytes) -> list[Message]:
        """Parse ``data`` (any split of the stream); returns the accepted MAVLink 2 messages."""
        self.bytes_in += len(data)
        out: list[Message] = []
        for msg in self.mav.parse_buffer(data) or ():
            kind = msg.get_type()
            if kind == "BAD_DATA":
                reason = str(getattr(msg, "reason", ""))
                if "signature" in reason.lower():
                    self.rejected["bad_signature"] += 1
                elif "crc" in reason.lower():
                    self.rejected["bad_crc"] += 1
                else:
                    self.rejected["garbage"] += 1
                continue
            buf = msg.get_msgbuf()
            if not buf or buf[0] != MAGIC_V2:
                self.rejected["mavlink1"] += 1
                continue
            self.accepted += 1
            out.append(msg)
        return out

    def encode(self, msg: Message) -> bytes:
        """Frame ``msg`` as MAVLink 2 (signed when the link has a key); advances the sequence."""
        return bytes(msg.pack(self.mav))
