"""The dialog manager: SNS (voluntary tasks, a state machine); it speaks the supervisor's alarms.

An utterance is interpreted with every grammar, then checked command by command against the
state the drone will be in when that command runs (the active grammars of states.xml and the
transition table of states.py): one refused command refuses the sentence, with the reason, and
nothing runs. Accepted commands run in spoken order through the task manager; emergency, and a
leading land/hover, bypass the queue. The safety monitors (ANS) are the vehicle's
(:mod:`drone.supervisor`): they act on the drone themselves, and the dialog hears their alarms
(:meth:`DialogManager.hear`), says them and follows the state they put the drone in.

An utterance that carries when it was issued (REST's ``issued``, rosbridge's, or the graph's
:attr:`~server.graph.Graph.issued`) is judged as it is handed to the drone
(drone/deadline.py): a sentence with a motion command that comes too late is not run ("Not
flown: …", audited as ``expired``); one of stops only always runs.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import json
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any, Protocol

from drone.commands import (
    Cancel,
    Describe,
    Emergency,
    Help,
    Hover,
    InvalidCommand,
    Land,
    PatrolControl,
    Query,
    parse_command,
)
from drone.deadline import DEFAULT_DEADLINE_S, STOPS, Deadline, Expired, audit_outcome, not_flown
from drone.preflight import EMERGENCY_DOWN, DroneFacts, refusal
from drone.supervisor.alarms import Alarm
from server.dialog import assist, clarify, confirm, replies
from server.dialog.addressing import parse_address, recipients
from server.dialog.defaults import fill_defaults
from server.dialog.errors import IllegalTransition
from server.dialog.ports import (
    DescribePort,
    DroneView,
    FleetPort,
    TaskPort,
    TaskReport,
    VehiclePort,
)
from server.dialog.states import MOTION, STATELESS, State, next_state
from server.language.nlu import NLU, Interpretation, default_nlu
from server.msgs import header

log = logging.getLogger(__name__)

UTTERANCE = "/console/utterance"
REPLY = "/console/reply"
STATE = "/console/state"
INTERPRET = "/console/interpret"
PREEMPTING = ("emergency", "land", "hover")
RECONCILE_PERIOD_S = 0.25  # how soon the dialog follows a change it did not make
# the whole fleet's (server/fleet/central.py), not this drone's state
FLEET_ACTIONS = ("patrol_start", "patrol_stop", "patrol_pause", "patrol_resume")
# Task-manager notices the operator hears and their levels; "failed" covers
# a search that gave up.
NOTICES = {"marker_lost": "warn", "marker_found": "info", "progress": "info"}


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
    confirm_floor: float = 0.3  # speech from here up to the threshold: "Did you say …?"
    battery_low_pct: float = 25.0  # a take-off below it is refused (the supervisor's low)
    command_deadline_s: float = DEFAULT_DEADLINE_S

    @classmethod
    def from_settings(cls, settings: Any) -> DialogParams:
        names = cls.__dataclass_fields__
        return cls(**{n: getattr(settings, n) for n in names if hasattr(settings, n)})


@dataclass(frozen=True)
class DialogResult:
    reply: str
    commands: list[dict[str, Any]]
    accepted: bool
    # What the reply waits for: "confirm" when it asks "Did you say …?" (a yes runs it, a no
    # drops it: the console shows Yes / No buttons), else "".
    expects: str = ""
    expired: Expired | None = None  # not run: handed to the drone past its deadline


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
        fleet: FleetPort | None = None,
        drones: Callable[[], list[str]] | None = None,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        """Args: ``prefix`` ("/uav2" in a fleet) goes before the state topic and the interpret
        service; utterances carry a ``drone`` field and are filtered by ``drone``, unless the
        sentence names its drones ("uav2 land", "all drones land"); ``drones`` lists every
        drone's name (for "there is no drone uav5"); ``wall_clock``: Unix seconds, the clock
        of an utterance's ``issued``."""
        self.params = (
            params if isinstance(params, DialogParams) else DialogParams.from_settings(params)
        )
        self.graph = graph
        self.tasks = task_port
        self.vehicle = vehicle_port
        self.describer = describe_port
        self.store = store
        self.clock = clock
        self.wall_clock = wall_clock
        self.deadline = Deadline(self.params.command_deadline_s)
        self.nlu = nlu or default_nlu()
        self.drone = drone
        self.fleet = fleet
        self.drones = drones or (lambda: [drone])
        self._emergency_seen = False  # the drone's emergency bit seen since EMERGENCY began
        self.state_topic = f"{prefix}{STATE}"
        self.interpret_service = f"{prefix}{INTERPRET}"
        self._state = State.LANDED
        self._question: clarify.Question | None = None  # "Which chair?" awaiting its answer
        self._confirm: confirm.Pending | None = None  # "Did you say …?" awaiting a yes
        self._asked: dict[str, Any] | None = None
        self._pending: set[asyncio.Task[Any]] = set()
        self.replies: list[dict[str, Any]] = []  # every reply published (newest last), bounded
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
        alarm: str = "",
        expects: str = "",
    ) -> None:
        msg = {
            "header": header(now=None),
            "text": text,
            "level": level,
            "speak": True,
            "utterance": utterance,
            "commands": json.dumps(commands or []),
            "drone": self.drone,
            "alarm": alarm,
            "expects": expects,
        }
        self.replies.append(msg)
        del self.replies[:-200]
        if self.graph is not None:
            self.graph.publish(REPLY, msg)

    def _log(self, **kw: Any) -> None:
        if self.store is None:
            return
        row = {"drone": self.drone, "state": self._state.value, "now": None, **kw}
        later = getattr(self.store, "append_later", None)
        # A spoken stop must reach the wire before the fsync of its audit row: the driver sends
        # from this loop (bench/direct_actions.py measures the same for buttons).
        if later is not None and any(c.get("action") in PREEMPTING for c in kw["commands"]):
            later(**row)
        else:
            self.store.append(**row)

    # -- utterances ---------------------------------------------------------------------------
    def _on_utterance_msg(self, msg: Mapping[str, Any]) -> None:
        if msg.get("answered"):  # a REST or speech door's record of what it had answered
            return
        drone = str(msg.get("drone") or "")
        text = str(msg.get("text", ""))
        address = parse_address(text)
        asked_by = str(msg.get("asked_by") or "")
        if (
            not address.addressed
            and asked_by in self.drones()
            and self.nlu.answer(address.text) is not None
        ):
            # A bare yes or no answers the drone whose question the console has open, whichever
            # drone is selected: only that one takes it.
            if asked_by != self.drone:
                return
        elif address.addressed:
            selected = drone or self.drone
            targets = recipients(address, selected, self.drones())
            if self.drone not in targets:
                if not targets and selected == self.drone:
                    named = ", ".join(address.names or ())
                    here = ", ".join(self.drones())
                    self._reply(f"There is no drone {named}. Drones here: {here}.", "warn", text)
                return
        elif drone and drone != self.drone:
            return
        coro = self._answer_heard(
            text,
            confidence=float(msg.get("confidence", 1.0) or 0.0),
            source=str(msg.get("source") or "speech"),
            issued=getattr(self.graph, "issued", None),  # when the operator said it
        )
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            asyncio.run(coro)  # lockstep: no loop running, handle it now
            return
        task = loop.create_task(coro)
        self._pending.add(task)
        task.add_done_callback(self._pending.discard)

    async def _answer_heard(
        self, text: str, *, confidence: float, source: str, issued: float | None
    ) -> None:
        """A sentence heard on the graph, answered there: a drone that cannot be reached now
        (a vehicle process not joined, or silent) is said, not lost in a task."""
        try:
            await self.handle_utterance(text, confidence=confidence, source=source, issued=issued)
        except Exception as exc:  # the task's end: nobody else would see it
            log.warning("%s: %r not answered: %s", self.drone, text, exc)
            self._reply(f"{self.drone}: {exc}", "warn", text)

    async def _interpret_service(self, args: Mapping[str, Any]) -> dict[str, Any]:
        state = args.get("state") or None
        return {"commands": self.nlu.interpret(str(args.get("text", "")), state)}

    async def handle_utterance(
        self,
        text: str,
        confidence: float = 1.0,
        source: str = "text",
        role: str = "pilot",
        issued: float | None = None,
    ) -> DialogResult:
        """Interpret, check, execute and answer one utterance (also logged to the audit log:
        an intent row before acting, the outcome after).

        A sentence that names its drone ("uav2, land") is answered with the drone's name; the
        caller has already routed it here (``addressing.recipients``). ``issued`` (Unix
        seconds, None: no deadline): when the operator gave it; a sentence with a motion
        command handed to the drone past the deadline is not run (action ``expired``)."""
        self._log(
            utterance=text,
            commands=[],
            action="intent:utterance",
            outcome="pending",
            role=role,
            source=source,
            confidence=confidence,
        )
        result, action = await self._handle(text, confidence, source, role, issued)
        if self._confirm is not None:  # asked now, or a yes heard badly: still asking
            result = replace(result, expects="confirm")
        level = "info" if result.accepted else "warn"
        said = result.reply
        if parse_address(text).addressed and not said.startswith(f"{self.drone}:"):
            said = f"{self.drone}: {said}"
            result = replace(result, reply=said)
        self._reply(said, level, text, result.commands, expects=result.expects)
        late = result.expired
        self._log(
            utterance=text,
            commands=result.commands,
            action=action,
            outcome=f"{audit_outcome(late)}. {result.reply}" if late else result.reply,
            role=role,
            source=source,
            confidence=confidence,
        )
        return result

    async def _handle(
        self, text: str, confidence: float, source: str, role: str, issued: float | None = None
    ) -> tuple[DialogResult, str]:
        heard = source != "speech" or confidence >= self.params.confidence_threshold
        sentence = parse_address(text).text  # without the drone's name: "uav2, yes" is a yes
        said = self.nlu.answer(sentence)  # "yes", "no" or None: not an answer
        pending, self._confirm = self._confirm, None
        if pending is not None and pending.fresh(self.clock()):
            if said is not None and not heard:
                self._confirm = pending  # the answer itself was not heard well: still asking
                return DialogResult(replies.LOW_CONFIDENCE, [], False), "asked_repeat"
            if said == "no":
                return DialogResult(confirm.NOT_CONFIRMED, [], False), "not_confirmed"
            if said == "yes":  # the sentence runs now, checked against the state of now
                return await self._handle(pending.text, 1.0, "text", role, issued)
        elif heard and said is not None:  # a yes or no, and nothing asked
            why = confirm.EXPIRED if pending is not None else confirm.NOTHING_ASKED
            return DialogResult(why, [], False), "not_understood"
        if source == "speech" and self.vehicle.snapshot().flying:
            spoken = self.nlu.parse(sentence)
            if confirm.doubtful_emergency(spoken, confidence, self.params.confidence_threshold):
                return await self._hover_and_ask(text, spoken)
        if not heard:
            return self._low_confidence(text, sentence, confidence)
        interp: Interpretation = self.nlu.parse(sentence)
        commands = fill_defaults(interp.commands, self.vehicle.marker_ids())
        if not commands:
            if "minus" in interp.normalised.split():  # a signed number (nlu.py keeps the sign)
                return DialogResult(replies.NEGATIVE_AMOUNT, [], False), "not_understood"
            reply = assist.not_understood(text, self.nlu)
            return DialogResult(reply, [], False), "not_understood"
        if interp.unparsed:
            part = " ".join(interp.unparsed)
            return DialogResult(
                f"I did not understand '{part}'. Please rephrase the whole command.",
                commands,
                False,
            ), "partly_understood"
        if role != "pilot" and any(c["action"] not in STATELESS for c in commands):
            return DialogResult(replies.OBSERVER, commands, False), "refused"
        question, self._question = self._question, None
        if clarify.is_answer(interp):
            done = clarify.complete(question, interp, self.clock())
            if isinstance(done, str):
                self._question = question  # still waiting for a usable answer
                return DialogResult(done, commands, False), "refused"
            interp, commands = done, done.commands
        else:
            question = None  # any other sentence drops the question
        refusal = self._check(interp)
        if refusal is not None and await self._refreshed():  # the refusal may be of the past
            refusal = self._check(interp)
        if refusal is not None:
            return DialogResult(refusal, commands, False), "refused"
        late = self._late(commands, issued)
        if late is not None:  # judged here, as the sentence is handed to the drone
            self._question = question  # a question still open stays open
            reply = not_flown(text, late)
            return DialogResult(reply, commands, False, expired=late), "expired"
        self._asked = None
        reply, ok = await self._execute(commands)
        asked = next((i for i, p in enumerate(interp.parsed) if p.command == self._asked), None)
        if asked is not None:
            self._question = clarify.Question(interp.parsed, asked, self.clock())
        elif not ok and question is not None:
            self._question = question  # an answer that fits nothing: the question stands
        return DialogResult(reply, commands, ok), "executed" if ok else "refused"

    async def _refreshed(self) -> bool:
        """Bring the drone's snapshot up to now before a refusal is said; False: it already
        is (a drone in this process), or the drone did not answer in time."""
        return False

    def _late(self, commands: list[dict[str, Any]], issued: float | None) -> Expired | None:
        """The expiry of a sentence issued at ``issued`` if handed over now, else None."""
        if issued is None:
            return None
        kinds = [str(c.get("action", "")) for c in commands]
        verdict = self.deadline.judge_all(kinds, issued, self.wall_clock())
        return verdict if isinstance(verdict, Expired) else None

    async def _hover_and_ask(self, text: str, spoken: Interpretation) -> tuple[DialogResult, str]:
        """A spoken emergency heard doubtfully in flight: hover now, ask before cutting."""
        await self._execute([{"action": "hover"}])
        self._confirm = confirm.Pending(text, self.clock())
        ask = confirm.emergency_question(spoken.normalised)
        return DialogResult(ask, spoken.commands, False), "hovered_asked"

    def _low_confidence(
        self, text: str, sentence: str, confidence: float
    ) -> tuple[DialogResult, str]:
        """Speech under the threshold (``sentence``: ``text`` without its drone's name): "Did
        you say …?" when the grammars understand all of it and its confidence reaches
        ``confirm_floor`` (:mod:`server.dialog.confirm`), else "please repeat"."""
        p = self.params
        interp = confirm.to_read_back(
            self.nlu, sentence, confidence, p.confidence_threshold, p.confirm_floor
        )
        if interp is not None:
            self._confirm = confirm.Pending(text, self.clock())
            ask = confirm.question(interp.normalised, interp.commands)
            return DialogResult(ask, interp.commands, False), "asked_confirm"
        return DialogResult(replies.LOW_CONFIDENCE, [], False), "asked_repeat"

    def _check(self, interp: Interpretation) -> str | None:
        """The reason to refuse the sentence, or None: each command in its predicted state.

        The state is first brought up to the drone's snapshot of now (the periodic
        :meth:`step` may not have seen the last change yet). A stop the state would refuse
        still goes when the snapshot cannot say the drone is down: no fresh link (a console
        that has just adopted a flying vehicle, or one whose telemetry lags) — the vehicle
        answers it (DESIGN §5: stops always get through)."""
        snap = self.vehicle.snapshot()
        self._reconcile(snap)
        state = self._state
        known = self.vehicle.marker_ids()
        facts = DroneFacts(
            snap.emergency,
            snap.battery_pct,
            snap.link_ok,
            snap.flying,
            snap.battery_known,
            snap.navdata_doubt,
        )
        for p in interp.parsed:
            cmd = p.command
            action = cmd["action"]
            # The drone's own state first: "Taking off." must never precede "reset it first".
            why = refusal(action, facts, self.params.battery_low_pct)
            if why is not None and state in (State.LANDED, State.EMERGENCY, State.LANDING):
                return why
            if action in STOPS and not snap.link_ok:
                with contextlib.suppress(IllegalTransition):
                    state = next_state(state, action)
                continue
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
            if action in STATELESS or action in FLEET_ACTIONS:
                continue
            try:
                state = next_state(state, action)
            except IllegalTransition as exc:
                return exc.reason
        return None

    async def _execute(self, commands: list[dict[str, Any]]) -> tuple[str, bool]:
        """Run the sentence; (reply, accepted). The task manager may refuse it as a whole.

        Each command is read as the typed union (drone/commands.py) and handled by its type:
        the dialog's own (help, query, describe, the fleet's patrol, cancel) here, stops at
        once, the rest queued for the task manager as said."""
        said: list[str] = []
        queue: list[dict[str, Any]] = []
        try:
            typed = [parse_command(c) for c in commands]
        except InvalidCommand as exc:  # a grammar edited to say what no command is
            return assist.operator_words(str(exc)), False
        for i, (cmd, command) in enumerate(zip(commands, typed, strict=True)):
            action = command.action
            match command:
                case Help():
                    said.append(assist.help_text(self._state))
                case Query(item=item):
                    said.append(
                        replies.answer(item or "state", self.vehicle.snapshot(), self._state)
                    )
                case Describe():
                    said.append(await self._describe())
                case PatrolControl() if action != "patrol_stop" or self._fleet_may_run():
                    ok, text = await self._fleet_command(command)
                    if ok or action != "patrol_stop":
                        said.append(text)
                    else:  # no fleet patrol running: stop this drone's own task
                        said.append(self._cancel_own(queue))
                case Cancel() | PatrolControl():  # a patrol_stop with no fleet: this drone's own
                    said.append(self._cancel_own(queue))
                case Emergency() | Land() | Hover() if isinstance(command, Emergency) or (
                    not queue and not _motion_before(commands, i)
                ):
                    self.tasks.preempt(cmd)
                    self._event(action)
                    said.append(replies.confirmation(cmd) + ".")
                case _:
                    queue.append(cmd)
                    said.append(replies.confirmation(cmd) + ".")
        if queue:
            # A task manager in this process answers at once; a vehicle's, after its reply.
            answer = self.tasks.submit(list(queue))
            if inspect.isawaitable(answer):
                answer = await answer
            decisions = list(answer)
            refused = [d for d in decisions if not d.accepted]
            asking = [c for c, d in zip(queue, decisions, strict=False) if d.question]
            if asking:  # "Which chair? …": the next answer completes this command
                self._asked = asking[0]
                return next(d.reason for d in decisions if d.question), False
            if refused:
                return assist.operator_words(refused[0].reason or "I cannot do that now."), False
            for cmd in queue:
                self._event(cmd["action"])
        return _merge(said), True

    def _fleet_may_run(self) -> bool:
        """Whether a fleet patrol may be running: asked of a port in this process
        (``running()``); a remote one is asked to stop and says whether one ran."""
        if self.fleet is None:
            return False
        running = getattr(self.fleet, "running", None)
        return True if running is None else bool(running())

    def _cancel_own(self, queue: list[dict[str, Any]]) -> str:
        queue.clear()
        self.tasks.cancel()
        self._event("cancel")
        return "OK, cancelled."

    async def _fleet_command(self, cmd: PatrolControl) -> tuple[bool, str]:
        """Start, stop, pause or resume the Central patrol (the console's buttons do the
        same): (ok, reply).

        The fleet port answers at once in the server's process, or, from a vehicle process,
        after a call to the central server (an awaitable)."""
        fleet = self.fleet
        if fleet is None:
            return False, "There is no fleet manager here to run a patrol."
        verb = cmd.action.removeprefix("patrol_")
        # One fixed method per action (a port may lack one: said, not raised).
        method = {
            "patrol_start": getattr(fleet, "start", None),
            "patrol_stop": getattr(fleet, "stop", None),
            "patrol_pause": getattr(fleet, "pause", None),
            "patrol_resume": getattr(fleet, "resume", None),
        }[cmd.action]
        if method is None:
            return False, f"The fleet manager here cannot {verb} a patrol."
        reply = method()
        if inspect.isawaitable(reply):
            reply = await reply
        return bool(reply.ok), str(reply.text)

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
    def _on_task_event(self, ev: TaskReport) -> None:
        kind = ev.kind
        if kind == "done" and ev.command:
            self._reply(ev.detail or replies.result(ev.command))
        elif kind == "failed":
            why = f": {ev.detail}" if ev.detail else ""
            what = "the task" if ev.detail or not ev.command else replies.confirmation(ev.command)
            if ev.command.get("action") == "search":
                what = "the search"  # the search gave up
            self._reply(
                f"I could not finish {what.lower()}{why}.",
                "warn",
            )
        elif kind == "landed" and ev.command.get("action") == "emergency":
            self._reply(EMERGENCY_DOWN, "warn")
        elif kind == "landed":
            self._reply("Landed.")
        elif kind in NOTICES and ev.detail:  # search started / marker found / leg reached
            self._reply(
                ev.detail + ("" if ev.detail.endswith((".", "?", "!")) else "."), NOTICES[kind]
            )
        if kind == "started":
            action = str(ev.command.get("action", ""))
            if action in MOTION or action == "return_home":
                self._event(action)
            return
        self._event(kind)

    # -- following the drone, speaking its alarms ---------------------------------------------
    def step(self, now: float) -> None:
        """Follow the drone where it changed without the dialog (lockstep: every tick)."""
        self._reconcile(self.vehicle.snapshot())

    def hear(self, alarm: Alarm) -> None:
        """An alarm of the drone's supervisor: it already acted; follow the state its action
        puts the drone in, say it, and audit it."""
        if alarm.action is not None:
            self._event(alarm.action.event)
        self._reply(alarm.text, alarm.severity.value, alarm=alarm.monitor)
        self._log(
            utterance="",
            commands=[alarm.action.command()] if alarm.action else [],
            action=f"ans:{alarm.monitor}",
            outcome=alarm.text,
            role="system",
            source="ans",
        )

    def _reconcile(self, snap: DroneView) -> None:
        """Follow the drone where it changed without the dialog.

        Buttons, ``/ardrone/*`` topics, other clients and the drone itself (its own landing,
        an emergency cut-out) change what it is doing; the dialog state must follow, or a
        spoken "land" would be refused while the drone flies.
        """
        if not snap.link_ok:
            return
        if snap.emergency:
            self._emergency_seen = True
            self._set_state(State.EMERGENCY)
            return
        if self._state is State.EMERGENCY:
            if self._emergency_seen:  # the drone left its emergency (Reset, or another client)
                self._emergency_seen = False
                self._set_state(State.LANDED)
            return
        grounded = (State.LANDED, State.EMERGENCY)
        airborne = (State.AIRBORNE_IDLE, State.EXECUTING, State.SEARCHING, State.RETURNING)
        if snap.flying and self._state in grounded:
            self._set_state(State.AIRBORNE_IDLE)
        elif not snap.flying and self._state in airborne:
            self._set_state(State.LANDED)

    def announce(self, text: str, level: str = "info") -> None:
        """Say ``text`` to every console (a refusal of a button, an alert)."""
        self._reply(text, level)

    def note_direct(self, action: str) -> None:
        """A button or REST call acted on the drone directly: follow it at once.

        The snapshot would tell within an ANS period; the next sentence must not wait for it
        (a typed "take off" right after EMERGENCY STOP is refused, not accepted).
        """
        self._confirm = None  # a "yes" after a button never runs what was asked before it
        if action == "reset" and self._state is State.EMERGENCY:
            self._emergency_seen = False
            self._set_state(State.LANDED)
        elif action in ("emergency", "land", "hover"):
            self._event(action)

    async def run(self, period_s: float | None = None) -> None:
        """Real time: follow the drone (:meth:`step`) on absolute deadlines until cancelled."""
        loop = asyncio.get_running_loop()
        period = period_s or RECONCILE_PERIOD_S
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
    "Searching",
)


def _is_confirmation(s: str) -> bool:
    return s.startswith(_CONFIRM_STARTS) or s.startswith(tuple(x.lower() for x in _CONFIRM_STARTS))
