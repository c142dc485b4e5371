"""A vehicle's task executor as a console's dialog drives it (the vehicle runs no dialog).

The console's dialog understands a sentence and hands the vehicle typed commands
(drone/commands.py) through the control ops ``submit`` (``commands``: a sentence, queued in
order; ``replace``), ``preempt`` (``command``: land, hover, emergency or return home at once, or
one command that replaces everything; ``by``) and ``cancel``; each is answered with the task
executor's own decisions. Its notices go to the console on ``/NAME/vehicle/task_event``
(:func:`notice_message`), with the executor's state when the notice was given, so the dialog
can tell when the drone has gone idle.

A ``submit`` or ``preempt`` that carries when the operator gave it (``issued``) is judged
again as the vehicle receives it (drone/deadline.py): one with a motion command past the
deadline is not run and is answered ``expired`` (its age and the deadline), with the operator's
"Not flown" line as the reason; stops and cancel never expire.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from drone.commands import InvalidCommand, parse_command
from drone.deadline import Deadline, Expired, label, not_flown
from server.tasks.manager import Decision, TaskManager, TaskNotice
from server.vehicles.errors import VehicleError

TASK_OPS = ("submit", "preempt", "cancel")
# What TaskManager.preempt runs itself; any other preempted command replaces the queue.
SAFETY_ACTIONS = frozenset({"land", "emergency", "return_home", "hover"})


def _decision(d: Decision) -> dict[str, Any]:
    return {"accepted": bool(d.accepted), "reason": str(d.reason), "question": bool(d.question)}


def expired_answer(op: str, actions: Sequence[str], verdict: Expired) -> dict[str, Any]:
    """The answer to a task op not run because it came past its deadline: ``expired`` (age
    and deadline, as a direct action's), the "Not flown" line, and for a ``submit`` one
    refusal per command."""
    detail = not_flown(" then ".join(label(a) for a in actions), verdict)
    out: dict[str, Any] = {
        "accepted": False,
        "detail": detail,
        "expired": {"age_s": verdict.age_s, "deadline_s": verdict.deadline_s},
    }
    if op == "submit":
        out["decisions"] = [{"accepted": False, "reason": detail, "question": False}] * len(actions)
    return out


def run_task_op(
    tasks: TaskManager,
    op: str,
    args: dict[str, Any],
    *,
    issued: float | None = None,
    now: float = 0.0,
    deadline: Deadline | None = None,
) -> dict[str, Any]:
    """One task op (see the module docstring) on ``tasks``; its answer.

    ``issued``: when the operator gave it, on the vehicle's clock (None: no deadline);
    ``now``: the vehicle's clock as it received it; ``deadline``: the rule (the default 2 s).

    Raises:
        VehicleError: an unknown op, or commands that are not typed commands (the reason).
    """
    rule = deadline or Deadline()
    if op == "cancel":
        return {"accepted": True, "cancelled": tasks.cancel()}
    if op == "submit":
        raw = args.get("commands")
        if not isinstance(raw, list) or not raw:
            raise VehicleError("submit: commands must be a non-empty list")
        try:
            commands = [parse_command(c) for c in raw]
        except InvalidCommand as exc:
            raise VehicleError(f"submit: {exc}") from exc
        actions: list[str] = [c.action for c in commands]
        if issued is not None:
            verdict = rule.judge_all(actions, issued, now)
            if isinstance(verdict, Expired):
                return expired_answer(op, actions, verdict)
        decisions = tasks.submit(commands, replace=args.get("replace") is True)
        return {"decisions": [_decision(d) for d in decisions]}
    if op == "preempt":
        command = args.get("command")
        try:
            typed = parse_command(command)
        except InvalidCommand as exc:
            raise VehicleError(f"preempt: {exc}") from exc
        assert isinstance(command, dict)
        if issued is not None:
            verdict = rule.judge(typed.action, issued, now)
            if isinstance(verdict, Expired):
                return expired_answer(op, [typed.action], verdict)
        if typed.action in SAFETY_ACTIONS and len(command) == 1:
            decision = tasks.preempt(typed.action, by=str(args.get("by", ""))[:64])
        else:  # a supervisor's correction, "move down 0.4 m", replacing everything
            decision = tasks.submit([typed], replace=True)[0]
        return {"accepted": bool(decision.accepted), "detail": str(decision.reason)}
    raise VehicleError(f"unknown task op {op!r} ({', '.join(TASK_OPS)})")


def notice_message(notice: TaskNotice, tasks: TaskManager) -> dict[str, Any]:
    """A task notice as ``/NAME/vehicle/task_event`` carries it (JSON-ready), with the
    executor's state and queue length at that moment."""
    status = tasks.status
    return {
        "kind": str(notice.kind),
        "text": str(notice.text or ""),
        "task": str(notice.task or ""),
        "state": str(status.state),
        "queued": int(status.queued),
    }
