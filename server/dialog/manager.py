"""The dialog and system manager: SNS (voluntary tasks, a state machine) + ANS (monitors).

An utterance is interpreted with every grammar, then checked command by command against the
state the drone will be in when that command runs (the active grammars of states.xml and the
transition table of states.py): one refused command refuses the sentence, with the reason, and
nothing runs. Accepted commands run in spoken order through the task manager; emergency, and a
leading land/hover, bypass the queue. ANS alarms preempt voluntary tasks and are spoken.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

from server.dialog import replies
from server.dialog.autonomic import (
    Alarm,
    AltitudeMonitor,
    Autonomic,
    BatteryMonitor,
    LinkMonitor,
    MarkersLostMonitor,
)
from server.dialog.errors import IllegalTransition
from server.dialog.ports import DescribePort, TaskEvent, TaskPort, VehiclePort, VehicleSnapshot
from server.dialog.states import MOTION, STATELESS, State, next_state
from server.language.nlu import NLU, Interpretation, default_nlu
from server.msgs import header

UTTERANCE = "/console/utterance"
REPLY = "/console/reply"
STATE = "/console/state"
INTERPRET = "/console/interpret"
PREEMPTING = ("emergency", "land", "hover")


class GraphLike(Protocol):
    def advertise(self, name: str, type: str, *, latch: bool = False) -> str: ...
    def publish(self, name: str, msg: dict[str, Any]) -> None: ...
    def subscribe(
        self, name: str, callback: Callable[[dict[str, Any]], None], *, type: str | None = None
    ) -> Any: ...
    def advertise_service(self, name: str, type: str, handler: Any) -> str: ...


class StoreLike(Protocol):
    """What the dialog needs of the audit log (``server.store.AuditLog``)."""

    def append(
        self,
        *,
        utterance: str,
        commands: list[dict[str, Any]],
        action: str,
        outcome: str,
        role: str = ...,
        source: str = ...,
        drone: str = ...,
        confidence: float | None = ...,
        state: str = ...,
        now: float | None = ...,
    ) -> int: ...


@dataclass(frozen=True)
class DialogParams:
    """The settings the dialog manager reads (names as in server.settings.Settings)."""

    confidence_threshold: float = 0.5
    battery_low_pct: float = 25.0
    battery_critical_pct: float = 12.0
    altitude_ceiling_m: float = 2.8
    ans_period_s: float = 0.5
    search_after_s: float = 1.5

    @classmethod
    def from_settings(cls, settings: Any) -> DialogParams:
        names = cls.__dataclass_fields__
        return cls(**{n: getattr(settings, n) for n in names if hasattr(settings, n)})


@dataclass(frozen=True)
class DialogResult:
    reply: str
    commands: list[dict[str, Any]]
    accepted: bool


class DialogManager:
    """One drone's dialog: subscribes utterances, publishes replies and its state."""

    def __init__(
        self,
        graph: GraphLike | None,
        params: DialogParams | Any,
        task_port: TaskPort,
        vehicle_port: VehiclePort,
        describe_port: DescribePort | None,
        store: StoreLike | None,
        clock: Callable[[], float],
        *,
        nlu: NLU | None = None,
        drone: str = "uav1",
        prefix: str = "",
    ) -> None:
        """Args: ``prefix`` ("/uav2" in a fleet) goes before the state topic and the interpret
        service; utterances carry a ``drone`` field and are filtered by ``drone``."""
        self.params = (
            params if isinstance(params, DialogParams) else DialogParams.from_settings(params)
        )
        self.graph = graph
        self.tasks = task_port
        self.vehicle = vehicle_port
        self.describer = describe_port
        self.store = store
        self.clock = clock
        self.nlu = nlu or default_nlu()
        self.drone = drone
        self.state_topic = f"{prefix}{STATE}"
        self.interpret_service = f"{prefix}{INTERPRET}"
        self._state = State.LANDED
        self._pending: set[asyncio.Task[Any]] = set()
        self.replies: list[dict[str, Any]] = []  # every reply published (newest last), bounded
        p = self.params
        self.ans = Autonomic(
            [
                BatteryMonitor(p.battery_low_pct, p.battery_critical_pct, period_s=p.ans_period_s),
                AltitudeMonitor(p.altitude_ceiling_m, period_s=p.ans_period_s),
                LinkMonitor(period_s=min(p.ans_period_s, 0.25)),
                MarkersLostMonitor(p.search_after_s, period_s=p.ans_period_s),
            ]
        )
        task_port.on_event(self._on_task_event)
        if graph is not None:
            graph.advertise(REPLY, "uav_console/Reply")
            graph.advertise(self.state_topic, "uav_console/DialogState", latch=True)
            graph.subscribe(UTTERANCE, self._on_utterance_msg, type="uav_console/Utterance")
            graph.advertise_service(
                self.interpret_service, "uav_console/Interpret", self._interpret_service
            )
        self._publish_state()

    # -- state --------------------------------------------------------------------------------
    @property
    def state(self) -> State:
        return self._state

    def grammars(self) -> list[str]:
        return self.nlu.active_grammars(self._state.value)

    def _set_state(self, new: State) -> None:
        if new is not self._state:
            self._state = new
            self._publish_state()

    def _event(self, event: str) -> None:
        # a task event that does not concern this state (e.g. "done" while hovering) is ignored
        with contextlib.suppress(IllegalTransition):
            self._set_state(next_state(self._state, event))

    def _publish_state(self) -> None:
        if self.graph is None:
            return
        self.graph.publish(
            self.state_topic,
            {
                "header": header(now=None),
                "drone": self.drone,
                "state": self._state.value,
                "grammars": self.grammars(),
            },
        )

    # -- replies ------------------------------------------------------------------------------
    def _reply(
        self,
        text: str,
        level: str = "info",
        utterance: str = "",
        commands: list[dict[str, Any]] | None = None,
    ) -> None:
        msg = {
            "header": header(now=None),
            "text": text,
            "level": level,
            "speak": True,
            "utterance": utterance,
            "commands": json.dumps(commands or []),
        }
        self.replies.append(msg)
        del self.replies[:-200]
        if self.graph is not None:
            self.graph.publish(REPLY, msg)

    def _log(self, **kw: Any) -> None:
        if self.store is not None:
            self.store.append(drone=self.drone, state=self._state.value, now=None, **kw)

    # -- utterances ---------------------------------------------------------------------------
    def _on_utterance_msg(self, msg: Mapping[str, Any]) -> None:
        drone = str(msg.get("drone") or "")
        if drone and drone != self.drone:
            return
        coro = self.handle_utterance(
            str(msg.get("text", "")),
            confidence=float(msg.get("confidence", 1.0) or 0.0),
            source=str(msg.get("source") or "speech"),
        )
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            asyncio.run(coro)  # lockstep: no loop running, handle it now
            return
        task = loop.create_task(coro)
        self._pending.add(task)
        task.add_done_callback(self._pending.discard)

    async def _interpret_service(self, args: Mapping[str, Any]) -> dict[str, Any]:
        state = args.get("state") or None
        return {"commands": self.nlu.interpret(str(args.get("text", "")), state)}

    async def handle_utterance(
        self, text: str, confidence: float = 1.0, source: str = "text", role: str = "pilot"
    ) -> DialogResult:
        """Interpret, check, execute and answer one utterance (also logged to the audit log)."""
        result, action = await self._handle(text, confidence, source, role)
        level = "info" if result.accepted else "warn"
        self._reply(result.reply, level, text, result.commands)
        self._log(
            utterance=text,
            commands=result.commands,
            action=action,
            outcome=result.reply,
            role=role,
            source=source,
            confidence=confidence,
        )
        return result

    async def _handle(
        self, text: str, confidence: float, source: str, role: str
    ) -> tuple[DialogResult, str]:
        if source == "speech" and not confidence >= self.params.confidence_threshold:
            return DialogResult(replies.LOW_CONFIDENCE, [], False), "asked_repeat"
        interp: Interpretation = self.nlu.parse(text)
        commands = interp.commands
        if not commands:
            return DialogResult(replies.NOT_UNDERSTOOD, [], False), "not_understood"
        if interp.unparsed:
            part = " ".join(interp.unparsed)
            return DialogResult(
                f"I did not understand '{part}'. Please rephrase the whole command.",
                commands,
                False,
            ), "partly_understood"
        if role != "pilot" and any(c["action"] not in STATELESS for c in commands):
            return DialogResult(replies.OBSERVER, commands, False), "refused"
        refusal = self._check(interp)
        if refusal is not None:
            return DialogResult(refusal, commands, False), "refused"
        reply, ok = await self._execute(commands)
        return DialogResult(reply, commands, ok), "executed" if ok else "refused"

    def _check(self, interp: Interpretation) -> str | None:
        """The reason to refuse the sentence, or None: each command in its predicted state."""
        state = self._state
        known = self.vehicle.marker_ids()
        for p in interp.parsed:
            cmd = p.command
            action = cmd["action"]
            active = self.nlu.grammar.active(state.value)
            if p.grammar not in active:
                spec = self.nlu.grammar.states.get(state.value)
                specific = _specific_reason(state, action)
                return specific or (
                    spec.refuse if spec and spec.refuse else "I cannot do that now."
                )
            markers = [cmd["marker"]] if "marker" in cmd else list(cmd.get("markers", []))
            for m in markers:
                if known and m not in known:
                    return replies.unknown_marker(m)
            if action in STATELESS:
                continue
            try:
                state = next_state(state, action)
            except IllegalTransition as exc:
                return exc.reason
        return None

    async def _execute(self, commands: list[dict[str, Any]]) -> tuple[str, bool]:
        """Run the sentence; (reply, accepted). The task manager may refuse it as a whole."""
        said: list[str] = []
        queue: list[dict[str, Any]] = []
        for i, cmd in enumerate(commands):
            action = cmd["action"]
            if action == "query":
                item = cmd.get("item", "state")
                said.append(replies.answer(item, self.vehicle.snapshot(), self._state))
            elif action == "describe":
                said.append(await self._describe())
            elif action == "cancel":
                queue.clear()
                self.tasks.cancel()
                self._event("cancel")
                said.append("OK, cancelled.")
            elif action == "emergency" or (
                action in PREEMPTING and not queue and not _motion_before(commands, i)
            ):
                self.tasks.preempt(cmd)
                self._event(action)
                said.append(replies.confirmation(cmd) + ".")
            else:
                queue.append(cmd)
                said.append(replies.confirmation(cmd) + ".")
        if queue:
            decisions = list(self.tasks.submit(list(queue)))
            refused = [d for d in decisions if not d.accepted]
            if refused:
                return refused[0].reason or "I cannot do that now.", False
            for cmd in queue:
                self._event(cmd["action"])
        return _merge(said), True

    async def _describe(self) -> str:
        if self.describer is None:
            return "I cannot describe the scene: the captioner is not available."
        try:
            return await asyncio.wait_for(self.describer.describe(), timeout=10.0)
        except TimeoutError:
            return "The scene description took too long."
        except Exception as exc:
            return f"I cannot describe the scene: {exc}"

    # -- task events --------------------------------------------------------------------------
    def _on_task_event(self, ev: TaskEvent) -> None:
        kind = ev.kind
        if kind == "done" and ev.command:
            self._reply(ev.detail or replies.result(ev.command))
        elif kind == "failed":
            why = f": {ev.detail}" if ev.detail else ""
            what = "the task" if ev.detail or not ev.command else replies.confirmation(ev.command)
            self._reply(
                f"I could not finish {what.lower()}{why}.",
                "warn",
            )
        elif kind == "landed":
            self._reply("Landed.")
        if kind == "started":
            action = str(ev.command.get("action", ""))
            if action in MOTION or action == "return_home":
                self._event(action)
            return
        self._event(kind)

    # -- ANS ----------------------------------------------------------------------------------
    def step(self, now: float) -> list[Alarm]:
        """Run the monitors due at ``now`` (lockstep); alarms are spoken and may preempt."""
        snap = self.vehicle.snapshot()
        self._reconcile(snap)
        alarms = self.ans.step(snap, self._state, now)
        for alarm in alarms:
            if alarm.action is not None:
                self.tasks.preempt(alarm.action)
                self._event(str(alarm.action["action"]))
            self._reply(alarm.text, alarm.level)
            self._log(
                utterance="",
                commands=[dict(alarm.action)] if alarm.action else [],
                action=f"ans:{alarm.monitor}",
                outcome=alarm.text,
                role="system",
                source="ans",
            )
        return alarms

    def _reconcile(self, snap: VehicleSnapshot) -> None:
        """Follow the drone where it changed without the dialog.

        Buttons, ``/ardrone/*`` topics, other clients and the drone itself (its own landing,
        an emergency cut-out) change what it is doing; the dialog state must follow, or a
        spoken "land" would be refused while the drone flies.
        """
        if not snap.link_ok:
            return
        grounded = (State.LANDED, State.EMERGENCY)
        airborne = (State.AIRBORNE_IDLE, State.EXECUTING, State.SEARCHING, State.RETURNING)
        if snap.flying and self._state in grounded:
            self._set_state(State.AIRBORNE_IDLE)
        elif not snap.flying and self._state in airborne:
            self._set_state(State.LANDED)

    async def run(self, period_s: float | None = None) -> None:
        """Real-time ANS runner: step on absolute deadlines until cancelled."""
        loop = asyncio.get_running_loop()
        period = period_s or min(m.period_s for m in self.ans.monitors)
        deadline = loop.time()
        while True:
            self.step(self.clock())
            deadline += period
            await asyncio.sleep(max(0.0, deadline - loop.time()))


def _motion_before(commands: list[dict[str, Any]], i: int) -> bool:
    return any(c["action"] not in STATELESS and c["action"] != "cancel" for c in commands[:i])


def _specific_reason(state: State, action: str) -> str | None:
    try:
        next_state(state, action)
    except IllegalTransition as exc:
        if "cannot do that" not in exc.reason:
            return exc.reason
    return None


def _merge(sentences: list[str]) -> str:
    """Join confirmations into one sentence: "Taking off, then flying to marker 2."."""
    out: list[str] = []
    for s in sentences:
        if out and out[-1].endswith(".") and _is_confirmation(s) and _is_confirmation(out[-1]):
            out[-1] = out[-1][:-1] + ", then " + s[:1].lower() + s[1:]
        else:
            out.append(s)
    return " ".join(out)


_CONFIRM_STARTS = (
    "Taking off",
    "Landing",
    "Holding",
    "Returning",
    "Climbing",
    "Descending",
    "Moving",
    "Turning",
    "Flying",
    "Patrolling",
    "Starting the patrol",
)


def _is_confirmation(s: str) -> bool:
    return s.startswith(_CONFIRM_STARTS) or s.startswith(tuple(x.lower() for x in _CONFIRM_STARTS))
