"""Commands on the bus (``uavc/<fleet>/<drone>/cmd``): one query per command, one reply per query.

Sans-I/O: bytes in, a frozen :class:`Command` out (or :class:`~drone.bus.errors.PayloadError`
with the reason); a :class:`CommandReply` the vehicle answers with. Schema version 1, JSON:

Command: ``v`` (1), ``id`` (the sender's id, echoed), ``op`` (:data:`OPS`), ``args`` (object),
``issued`` (Unix seconds on the sending console's clock, or null), ``console`` (the sending
console's name), ``pilot`` (who commands at that console; with ``console`` the lease holder).

The task ops (``submit``, ``preempt``, ``cancel``) carry typed commands
(:mod:`drone.commands`): what a console's dialog understood, for the vehicle's task executor,
and ``issued`` of the sentence, from which the vehicle judges its deadline again
(drone/deadline.py: a motion past it is refused with ``result.expired``; stops never expire).

Reply: ``v``, ``id``, ``accepted`` (bool), ``reason`` (why not; empty when accepted),
``result`` (the op's answer, an object), ``drone`` (who answered).
"""

from __future__ import annotations

import json
import math
from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from drone.bus.errors import PayloadError
from drone.commands import InvalidCommand, parse_command

MAX_COMMAND_BYTES = 16 * 1024
# What a vehicle answers: direct actions, its task executor's queue (a console's dialog
# submits what it understood), reads, simulator faults, its lease, jogs. ``utterance`` is
# decoded so that a console of another version is refused with the reason, not "unknown op".
Op = Literal[
    "direct",
    "submit",
    "preempt",
    "cancel",
    "utterance",
    "telemetry",
    "truth",
    "fault",
    "lease",
    "jog",
]
OPS: tuple[str, ...] = get_args(Op)
TASK_OPS = frozenset({"submit", "preempt", "cancel"})
# What ``preempt`` runs: the task executor's safety actions (TaskManager.preempt), or one
# command that replaces everything (a supervisor's descent).
PREEMPT_ACTIONS = frozenset({"land", "hover", "emergency", "return_home"})
# Actions any pilot may send, lease or not; they never wait behind anything (DESIGN §5).
STOP_ACTIONS = frozenset({"land", "hover", "emergency"})
DIRECT_ACTIONS = frozenset({"takeoff", "reset"}) | STOP_ACTIONS
# Ops that change nothing: any pilot may ask them, lease or not.
READ_OPS = frozenset({"telemetry", "truth"})
# A jog's velocity (``geometry_msgs/Twist`` as ``/cmd_vel`` carries it): these axes only.
JOG_AXES = {"linear": ("x", "y", "z"), "angular": ("z",)}


class Command(BaseModel):
    """A command to one vehicle (schema 1)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    v: Literal[1] = 1
    id: str = Field(min_length=1, max_length=96)
    op: Op
    args: dict[str, Any] = Field(default_factory=dict)
    issued: float | None = None  # Unix seconds, the sending console's clock
    console: str = Field(min_length=1, max_length=128)
    pilot: str = Field(min_length=1, max_length=128)

    @field_validator("issued")
    @classmethod
    def _finite(cls, value: float | None) -> float | None:
        if value is not None and not math.isfinite(value):
            raise ValueError("must be a finite number of Unix seconds")
        return value

    @property
    def holder(self) -> str:
        """The lease holder this command speaks for: ``pilot@console``."""
        return f"{self.pilot}@{self.console}"

    @property
    def action(self) -> str | None:
        """A direct command's action (``takeoff``, ``land`` …), or the action a ``preempt``
        runs; None for other ops."""
        if self.op == "preempt":
            command = self.args.get("command")
            value = command.get("action") if isinstance(command, dict) else None
            return value if isinstance(value, str) and len(command or {}) == 1 else None
        if self.op != "direct":
            return None
        value = self.args.get("action")
        return value if isinstance(value, str) else None

    @property
    def is_stop(self) -> bool:
        """Land, hover or emergency (a jog of zeros is a hover): any pilot's, ahead of
        anything queued."""
        if self.op == "jog":
            return all(v == 0 for v in _jog_values(self.args))
        return self.action in STOP_ACTIONS


class CommandReply(BaseModel):
    """The vehicle's answer to one :class:`Command` (schema 1)."""

    model_config = ConfigDict(frozen=True, extra="ignore")

    v: Literal[1] = 1
    id: str
    drone: str
    accepted: bool
    reason: str = ""
    result: dict[str, Any] = Field(default_factory=dict)


def encode_command(command: Command) -> bytes:
    return command.model_dump_json().encode()


def encode_reply(reply: CommandReply) -> bytes:
    return reply.model_dump_json().encode()


def _json_object(data: bytes, what: str, limit: int) -> Any:
    if len(data) > limit:
        raise PayloadError(f"{what} payload of {len(data)} bytes (at most {limit})")
    try:
        return json.loads(data)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise PayloadError(f"{what} is not JSON: {exc}") from exc


def _why(what: str, exc: ValidationError) -> PayloadError:
    first = exc.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "payload"
    return PayloadError(f"{what} {where}: {first['msg']}")


def decode_command(data: bytes) -> Command:
    """Decode one command payload and check its op's arguments.

    Raises:
        PayloadError: over 16 KB, not JSON, not the schema, an unknown op, or a direct action
            that is not one (the reason names the field).
    """
    raw = _json_object(data, "command", MAX_COMMAND_BYTES)
    op = raw.get("op") if isinstance(raw, dict) else None
    if isinstance(op, str) and op not in OPS:
        raise PayloadError(f"command op: unknown op {op!r} (one of {', '.join(OPS)})")
    try:
        command = Command.model_validate(raw)
    except ValidationError as exc:
        raise _why("command", exc) from exc
    if command.op == "direct" and command.action not in DIRECT_ACTIONS:
        raise PayloadError(
            f"command args.action: {command.args.get('action')!r} is not one of "
            f"{', '.join(sorted(DIRECT_ACTIONS))}"
        )
    if command.op == "utterance" and not isinstance(command.args.get("text"), str):
        raise PayloadError("command args.text: an utterance needs its text")
    if command.op == "jog":
        _check_jog(command.args)
    if command.op in ("submit", "preempt"):
        _check_tasks(command.op, command.args)
    return command


def _check_tasks(op: str, args: dict[str, Any]) -> None:
    """``submit``: ``commands``, a list of typed commands; ``preempt``: ``command``, one."""
    if op == "submit":
        commands = args.get("commands")
        if not isinstance(commands, list) or not commands:
            raise PayloadError("command args.commands: a submit needs a list of commands")
        where = [f"commands.{i}" for i in range(len(commands))]
    else:
        commands = [args.get("command")]
        where = ["command"]
        if not isinstance(commands[0], dict):
            raise PayloadError("command args.command: a preempt needs one command")
    for at, obj in zip(where, commands, strict=True):
        try:
            parse_command(obj)
        except InvalidCommand as exc:
            raise PayloadError(f"command args.{at}: {exc}") from exc


def _jog_values(args: dict[str, Any]) -> list[float]:
    out = []
    for part, axes in JOG_AXES.items():
        vec = args.get(part) or {}
        out += [float(vec.get(a, 0.0)) for a in axes] if isinstance(vec, dict) else [math.nan]
    return out


def _check_jog(args: dict[str, Any]) -> None:
    for part in JOG_AXES:
        vec = args.get(part, {})
        if not isinstance(vec, dict):
            raise PayloadError(f"command args.{part}: a jog's {part} is an object of axes")
        for axis, value in vec.items():
            if axis not in ("x", "y", "z"):
                raise PayloadError(f"command args.{part}.{axis}: not an axis")
            ok = isinstance(value, int | float) and not isinstance(value, bool)
            if not ok or not math.isfinite(value):
                raise PayloadError(f"command args.{part}.{axis}: must be a finite number")


def decode_reply(data: bytes) -> CommandReply:
    """Decode one reply payload.

    Raises:
        PayloadError: over 16 KB and more (replies carry telemetry: 256 KB), not JSON, or
            not the schema.
    """
    raw = _json_object(data, "reply", 16 * MAX_COMMAND_BYTES)
    try:
        return CommandReply.model_validate(raw)
    except ValidationError as exc:
        raise _why("reply", exc) from exc


def refusal(
    command_id: str, drone: str, reason: str, result: dict[str, Any] | None = None
) -> CommandReply:
    return CommandReply(
        id=command_id, drone=drone, accepted=False, reason=reason, result=result or {}
    )


def id_of(data: bytes) -> str:
    """The ``id`` of a payload that did not decode, when it has one (for the refusal)."""
    try:
        raw = json.loads(data[:MAX_COMMAND_BYTES])
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError, ValueError):
        return ""
    if isinstance(raw, dict) and isinstance(raw.get("id"), str):
        return str(raw["id"])[:96]
    return ""
