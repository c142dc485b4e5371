"""The command protocol, ground-station side: COMMAND_LONG/COMMAND_INT with COMMAND_ACK, one
command per id in flight, retries with ``confirmation``, IN_PROGRESS, chains (``then``), and
the high-level commands built on it (mode, arm and take-off, goto)."""

from __future__ import annotations

import math

from drone.mavlink.codec import Message, mav
from drone.mavlink.gcs.core import GcsCore, PendingCommand
from drone.mavlink.gcs.events import CommandProgress, CommandResult
from drone.mavlink.modes import custom_mode, intent_mode

FORCE_DISARM = 21196  # MAV_CMD_COMPONENT_ARM_DISARM param2: kill motors even in the air
RESULT_NAMES = {v.name.removeprefix("MAV_RESULT_"): k for k, v in mav.enums["MAV_RESULT"].items()}
_RESULTS = {k: v.name.removeprefix("MAV_RESULT_") for k, v in mav.enums["MAV_RESULT"].items()}
_COMMANDS = {k: v.name.removeprefix("MAV_CMD_") for k, v in mav.enums["MAV_CMD"].items()}


def command_name(command: int) -> str:
    """``MAV_CMD_NAV_TAKEOFF`` → ``"NAV_TAKEOFF"``."""
    return str(_COMMANDS.get(command, f"COMMAND_{command}"))


class CommandService(GcsCore):
    """Queue, send, retry and settle commands; DO_SET_MODE, arm and take-off, DO_REPOSITION."""

    def command(
        self,
        command: int,
        *params: float,
        now: float | None = None,
        use_int: bool = False,
        frame: int = mav.MAV_FRAME_GLOBAL_INT,
        then: list[tuple[int, tuple[float, ...]]] | None = None,
        urgent: bool = False,
    ) -> int:
        """Queue ``command`` with up to seven params; returns its token (in its CommandResult).

        ``then``: commands sent, in order, only after this one is ACCEPTED (arm, then take off).
        ``urgent``: send now even if a command with the same id is in flight (emergency).
        An identical command already waiting for its turn is not queued again; its token
        is returned instead.
        """
        now = self._now if now is None else now
        padded = tuple(float(p) for p in params) + (0.0,) * (7 - len(params))
        cmd = self._make(command, padded, use_int, frame)
        cmd.then = [
            self._make(c, tuple(p) + (0.0,) * (7 - len(p)), False, frame) for c, p in then or ()
        ]
        if urgent:
            self._inflight.pop(command, None)
            self._waiting.pop(command, None)
        busy = self._inflight.get(command)
        if busy is not None:
            for other in (busy, *self._waiting[command]):
                if other.params == padded and not other.then and not cmd.then:
                    return other.token
            self._waiting[command].append(cmd)
            return cmd.token
        self._start(cmd, now)
        return cmd.token

    def _make(
        self, command: int, params: tuple[float, ...], use_int: bool, frame: int
    ) -> PendingCommand:
        self._token += 1
        return PendingCommand(self._token, command, params, use_int, frame)

    def _start(self, cmd: PendingCommand, now: float) -> None:
        self._inflight[cmd.command] = cmd
        self._transmit(cmd, now)

    def _transmit(self, cmd: PendingCommand, now: float) -> None:
        ts, tc = self.telemetry.system_id or (self.target_system or 1), self.target_component
        p = cmd.params
        if cmd.use_int:
            msg = self.m.command_int_encode(
                ts,
                tc,
                cmd.frame,
                cmd.command,
                0,
                0,
                p[0],
                p[1],
                p[2],
                p[3],
                int(p[4]),
                int(p[5]),
                p[6],
            )
        else:
            msg = self.m.command_long_encode(ts, tc, cmd.command, min(cmd.attempts, 255), *p)
        cmd.attempts += 1
        cmd.sent_t = now
        self.commands_sent += 1
        self._send(msg)

    def _finish(
        self, cmd: PendingCommand, result: str, now: float, reason: str | None = None
    ) -> None:
        self._inflight.pop(cmd.command, None)
        self._events.append(CommandResult(cmd.token, command_name(cmd.command), result, reason))
        if result == "ACCEPTED" and cmd.then:
            nxt, rest = cmd.then[0], cmd.then[1:]
            nxt.then = rest
            if nxt.command in self._inflight:
                self._waiting[nxt.command].appendleft(nxt)
            else:
                self._start(nxt, now)
        elif cmd.then:
            cause = CommandResult(cmd.token, command_name(cmd.command), result, reason)
            for c in cmd.then:
                self._events.append(
                    CommandResult(
                        c.token,
                        command_name(c.command),
                        "NOT_SENT",
                        f"{command_name(cmd.command)} was not accepted",
                        cause,
                    )
                )
        queue = self._waiting.get(cmd.command)
        if queue and cmd.command not in self._inflight:
            self._start(queue.popleft(), now)

    def _on_ack(self, msg: Message, now: float) -> None:
        cmd = self._inflight.get(msg.command)
        if cmd is None:
            return  # a late duplicate ACK (retransmission answered twice): already settled
        result = _RESULTS.get(msg.result, str(msg.result))
        if msg.result == mav.MAV_RESULT_IN_PROGRESS:
            cmd.progress_t = now
            self._events.append(
                CommandProgress(cmd.token, command_name(cmd.command), int(msg.progress))
            )
            return
        reason = None
        if msg.result != mav.MAV_RESULT_ACCEPTED:
            # The explanation PX4/ArduPilot send as STATUSTEXT just before the ACK.
            recent = [st for t, st in self._texts if now - t <= 1.0 and t >= cmd.sent_t - 0.05]
            reason = recent[-1].text if recent else None
        self._finish(cmd, result, now, reason)

    def _check_commands(self, now: float) -> None:
        for cmd in list(self._inflight.values()):
            if cmd.progress_t is not None:
                if now - cmd.progress_t > 3.0 * self.command_timeout_s:
                    self._finish(cmd, "NO_ANSWER", now, "progress stopped")
                continue
            if now - cmd.sent_t < self.command_timeout_s:
                continue
            if cmd.attempts > self.retries:
                self._finish(cmd, "NO_ANSWER", now)
            else:
                self._transmit(cmd, now)

    def pending_commands(self) -> int:
        return len(self._inflight) + sum(len(q) for q in self._waiting.values())

    # ------------------------------------------------------------------ high-level commands
    def set_mode(self, name: str, now: float | None = None) -> int:
        """DO_SET_MODE to ``name`` (``"AUTO.LOITER"``, ``"GUIDED"``…)."""
        ap = self.telemetry.autopilot_id or mav.MAV_AUTOPILOT_PX4
        cm = custom_mode(ap, name)
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if ap == mav.MAV_AUTOPILOT_PX4:
            return self.command(
                mav.MAV_CMD_DO_SET_MODE, base, (cm >> 16) & 0xFF, (cm >> 24) & 0xFF, now=now
            )
        return self.command(mav.MAV_CMD_DO_SET_MODE, base, cm, now=now)

    def intent(self, intent: str, now: float | None = None) -> int:
        """Change to the mode that does ``intent`` (hold, rtl, land, mission, offboard)."""
        ap = self.telemetry.autopilot_id or mav.MAV_AUTOPILOT_PX4
        return self.set_mode(intent_mode(ap, intent), now)

    def arm_and_takeoff(self, rel_alt_m: float, now: float | None = None) -> int:
        """Arm, then NAV_TAKEOFF to ``rel_alt_m`` above home (sent only once armed).

        The arm is sent even when telemetry says armed: that flag is up to a heartbeat old, and
        a PX4 that has just auto-disarmed after landing denies a bare take-off. Arming an armed
        vehicle is accepted by PX4 and ArduPilot alike, so it costs one round trip.
        """
        home = self.telemetry.home
        alt = (home[2] + rel_alt_m) if home else math.nan
        Step = tuple[int, tuple[float, ...]]
        takeoff: Step = (
            mav.MAV_CMD_NAV_TAKEOFF,
            (-1.0, 0.0, 0.0, math.nan, math.nan, math.nan, alt),
        )
        arm: Step = (mav.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,))
        if self.telemetry.autopilot_id == mav.MAV_AUTOPILOT_ARDUPILOTMEGA:
            # ArduCopter takes off only in GUIDED (ArduCopter/mode_guided.cpp), with the
            # altitude relative to home in param7.
            takeoff = (takeoff[0], (0.0, 0.0, 0.0, math.nan, 0.0, 0.0, rel_alt_m))
            guided = float(custom_mode(mav.MAV_AUTOPILOT_ARDUPILOTMEGA, "GUIDED"))
            base = float(mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
            self.command(mav.MAV_CMD_DO_SET_MODE, base, guided, now=now, then=[arm, takeoff])
            return self._token
        self.command(arm[0], *arm[1], now=now, then=[takeoff])
        return self._token  # the take-off's token

    def goto(
        self,
        lat: float,
        lon: float,
        alt_amsl: float,
        heading_deg: float = math.nan,
        now: float | None = None,
    ) -> int:
        """DO_REPOSITION (COMMAND_INT, global): fly there and hold, the autopilot's own goto."""
        return self.command(
            mav.MAV_CMD_DO_REPOSITION,
            -1.0,
            float(mav.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE),
            0.0,
            heading_deg,
            round(lat * 1e7),
            round(lon * 1e7),
            alt_amsl,
            now=now,
            use_int=True,
            frame=mav.MAV_FRAME_GLOBAL,
        )
