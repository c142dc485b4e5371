"""One typed Settings model, read once from flags and ``UAVC_*`` environment variables, passed down.

Built on pydantic-settings: every field is also the variable ``UAVC_<FIELD>`` (``UAVC_PORT=9000``)
and the flag ``--<field>`` of ``serve`` and ``vehicle`` (generated in ``server/cli.py`` from the
field's annotation, description and topic, :func:`flags_of`), cast and validated once at start;
a value that cannot be used raises :class:`SettingsError` naming it. Each setting's one default
is the field's. ``docs/configuration.md`` is generated from this model
(``python -m server.settings``; a test fails when it is stale).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BeforeValidator, Field, ValidationError, field_validator, model_validator
from pydantic_settings import BaseSettings, EnvSettingsSource, NoDecode, SettingsConfigDict

from drone.deadline import DEFAULT_DEADLINE_S, check_deadline_s
from drone.share import SOURCE_ROOT, share_dir
from drone.sim.battery import FLIGHT_TIME_S
from server.http.map_tiles import DEFAULT_TILE_URL, check_tile_url

ROOT = SOURCE_ROOT  # the repository in a checkout (bench/, docs/)
ENV_PREFIX = "UAVC_"


def _split_commas(value: Any) -> Any:
    if isinstance(value, str):
        return tuple(s.strip() for s in value.split(",") if s.strip())
    return value


CommaList = Annotated[tuple[str, ...], NoDecode, BeforeValidator(_split_commas)]
"""A list: ``a,b`` in the environment (not JSON)."""


# The topics settings are grouped by in ``--help`` and in docs/configuration.md.
CONSOLE = "the console"
LIMITS = "limits on clients"
SAFETY = "safety (DESIGN §5)"
SPEECH = "language and speech"
TLS = "TLS"
MAVLINK = "MAVLink"
BUS = "the bus (Zenoh; docs/bus.md)"
VEHICLES = "vehicle processes"
RECORDER = "flight recorder"


def _topic(group: str, *aliases: str) -> dict[str, Any]:
    """A field's ``json_schema_extra``: its topic, and other flag names it answers to."""
    return {"group": group, "aliases": list(aliases)}


def group_of(name: str) -> str:
    """The topic of setting ``name`` (``--help`` groups its flag under it)."""
    extra = Settings.model_fields[name].json_schema_extra
    assert isinstance(extra, dict), name  # every field has one (_topic)
    return str(extra["group"])


def flags_of(name: str) -> list[str]:
    """The command-line flags of setting ``name``: ``--kebab-case`` first, then its aliases;
    a bool also has ``--no-…``."""
    flag = "--" + name.replace("_", "-")
    extra = Settings.model_fields[name].json_schema_extra
    given = extra.get("aliases") if isinstance(extra, dict) else None
    aliases = [str(a) for a in given] if isinstance(given, list) else []
    if Settings.model_fields[name].annotation is bool:
        return [flag, "--no-" + flag[2:], *aliases]
    return [flag, *aliases]


class SettingsError(ValueError):
    """A setting has a value that cannot be used; the message names it.

    ``names``: the settings a check refused (a check across settings names them in its message
    only)."""

    def __init__(self, message: str, names: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.names = names

    @classmethod
    def of(cls, exc: ValidationError) -> SettingsError:
        """The error for what pydantic refused: :func:`describe`'s message, the fields named."""
        names = tuple(str(e["loc"][0]) for e in exc.errors() if e["loc"])
        return cls(describe(exc), names)


class Settings(BaseSettings):
    """Everything that can be set, with its one default."""

    model_config = SettingsConfigDict(
        env_prefix=ENV_PREFIX, frozen=True, extra="ignore", validate_default=True
    )

    # -- the console ---------------------------------------------------------------------------
    host: str = Field(
        "127.0.0.1",
        description="Address the console listens on.",
        json_schema_extra=_topic(CONSOLE),
    )
    port: int = Field(
        8000, description="Port of the console (HTTP or HTTPS).", json_schema_extra=_topic(CONSOLE)
    )
    rosbridge_port: int | None = Field(
        None,
        description="Also serve rosbridge on this port (9090 by ROS custom).",
        json_schema_extra=_topic(CONSOLE),
    )
    drone: str = Field(
        "sim",
        description="'sim', 'sim-mavlink', 'none', an AR.Drone's IP or a MAVLink connection "
        "string (tcp:HOST:PORT, udpin:0.0.0.0:14550, …); a fleet may list one per drone, "
        "comma-separated.",
        json_schema_extra=_topic(CONSOLE),
    )
    world: str = Field(
        "indoor",
        description="indoor | outdoor | path to a world file.",
        json_schema_extra=_topic(CONSOLE),
    )
    fleet: int = Field(
        1,
        ge=0,
        description="Number of drones (0: a console with none of its own).",
        json_schema_extra=_topic(CONSOLE),
    )
    sim_base_addr: str = Field(
        "127.0.0.2",
        description="Loopback address of the first simulated drone; `serve` takes the next free "
        "one when another console has it, unless given as a flag.",
        json_schema_extra=_topic(CONSOLE, "--sim-addr"),
    )
    token: str | None = Field(
        None,
        description="Pilot token; generated and stored in data_dir on first start. A vehicle "
        "process: the token its safety door takes.",
        json_schema_extra=_topic(CONSOLE),
    )
    observer_token: str | None = Field(
        None, description="Observer (read-only) token.", json_schema_extra=_topic(CONSOLE)
    )
    allow_origins: CommaList = Field(
        (),
        description="Extra browser Origins allowed.",
        json_schema_extra=_topic(CONSOLE, "--allow-origin"),
    )
    allow_hosts: CommaList = Field(
        (),
        description="Host names (besides IP literals, localhost and --host) the server answers "
        "to: the DNS-rebinding guard refuses any other Host. '*' turns the guard off.",
        json_schema_extra=_topic(CONSOLE),
    )
    data_dir: Path = Field(
        default_factory=lambda: Path.home() / ".local/share/uav-console",
        description="Tokens, TLS material, audit log, recordings.",
        json_schema_extra=_topic(CONSOLE),
    )
    grammar_dir: Path = Field(
        default_factory=lambda: share_dir("grammars"),
        description="The NLU's XML grammars.",
        json_schema_extra=_topic(CONSOLE),
    )
    model_dir: Path = Field(
        default_factory=lambda: share_dir("models/captioner"),
        description="The ONNX image captioner.",
        json_schema_extra=_topic(CONSOLE),
    )
    open_browser: bool = Field(
        False,
        description="Open the console in a browser at start.",
        json_schema_extra=_topic(CONSOLE),
    )
    seed: int = Field(
        1, description="Seed of the simulator's randomness.", json_schema_extra=_topic(CONSOLE)
    )
    sim_speed: float = Field(
        1.0,
        description="Real-time factor of a socket-served simulator; autonomy is tuned for 1.",
        json_schema_extra=_topic(CONSOLE),
    )
    flight_time_s: float = Field(
        FLIGHT_TIME_S,
        gt=0.0,
        le=86400.0,
        description="A full battery's hover time, 100 % to 0 % (the AR.Drone 2.0's 12 minutes): "
        "the simulated AR.Drone flies it and the fleet's planner plans every drone with it.",
        json_schema_extra=_topic(CONSOLE),
    )
    clock_speed: float = Field(
        1.0,
        gt=0.0,
        le=100.0,
        description="The whole console (web process, vehicle processes, simulators) runs this "
        "many times faster than the wall clock; for tests and benchmarks, with the camera off "
        "(server/timewarp.py).",
        json_schema_extra=_topic(CONSOLE),
    )
    camera: bool = Field(
        True,
        description="Read the drones' video (off: no frames, no marker localisation).",
        json_schema_extra=_topic(CONSOLE),
    )
    # -- limits on clients ---------------------------------------------------------------------
    max_frame_bytes: int = Field(
        16 * 1024 * 1024,
        description="Largest rosbridge frame after authentication.",
        json_schema_extra=_topic(LIMITS),
    )
    rate_limit_per_s: float = Field(
        2000.0,
        description="rosbridge frames per second per connection (token bucket).",
        json_schema_extra=_topic(LIMITS),
    )
    rate_burst: int = Field(
        4000, description="Burst of that token bucket.", json_schema_extra=_topic(LIMITS)
    )
    # -- safety (DESIGN §5) --------------------------------------------------------------------
    heartbeat_timeout_s: float = Field(
        1.0,
        description="Operator lost while jogging, or console silent: hover after this.",
        json_schema_extra=_topic(SAFETY),
    )
    command_deadline_s: float = Field(
        DEFAULT_DEADLINE_S,
        description="A motion command handed to the drone later than this after the operator "
        "gave it is dropped, audited and reported (stops never expire; docs/deadlines.md).",
        json_schema_extra=_topic(SAFETY),
    )
    link_timeout_s: float = Field(
        0.5, description="No navdata for this long: link lost.", json_schema_extra=_topic(SAFETY)
    )
    battery_low_pct: float = Field(
        25.0, description="ANS: tell the operator, return home.", json_schema_extra=_topic(SAFETY)
    )
    battery_critical_pct: float = Field(
        12.0, description="ANS: land.", json_schema_extra=_topic(SAFETY)
    )
    altitude_ceiling_m: float | None = Field(
        None,
        description="ANS ceiling; unset: the world's (drone/limits.py); may only lower it.",
        json_schema_extra=_topic(SAFETY),
    )
    ans_period_s: float = Field(
        0.5, description="Period of the ANS checks.", json_schema_extra=_topic(SAFETY)
    )
    temperature_warn_c: float = Field(
        55.0,
        description="ANS: the drone's temperature (navdata) above this: tell the operator (5 °C "
        "under the 60 °C most Li-Po cells are rated to discharge at).",
        json_schema_extra=_topic(SAFETY),
    )
    temperature_land_c: float = Field(
        60.0,
        description="ANS: the drone's temperature above this: land (the Li-Po cells' rated "
        "discharge limit; the battery shares the hull with the thermometer).",
        json_schema_extra=_topic(SAFETY),
    )
    search_after_s: float = Field(
        1.5,
        description="Hovering with an uncertain position this long: search for a tag.",
        json_schema_extra=_topic(SAFETY),
    )
    central_loss_land_s: float = Field(
        20.0,
        description="A vehicle that hears no console hovers, then lands after this.",
        json_schema_extra=_topic(SAFETY),
    )
    # -- language and speech -------------------------------------------------------------------
    confidence_threshold: float = Field(
        0.5,
        description="Spoken commands at or above it run without a read-back.",
        json_schema_extra=_topic(SPEECH),
    )
    confirm_floor: float = Field(
        0.3,
        description="Spoken commands from this confidence up to the threshold are read back "
        "('Did you say …?') and run on a yes.",
        json_schema_extra=_topic(SPEECH),
    )
    asr_model: Path | None = Field(
        None,
        description="A CTranslate2 Whisper directory; unset: the bundled tiny.en.",
        json_schema_extra=_topic(SPEECH),
    )
    asr_model_sha256: str | None = Field(
        None, description="Expected SHA-256 of its model.bin.", json_schema_extra=_topic(SPEECH)
    )
    asr_workers: int = Field(
        0,
        description="Parallel decoders; 0: one per core less one.",
        json_schema_extra=_topic(SPEECH),
    )
    asr_queue: int = Field(
        4, description="Decodes waiting for a decoder before 503.", json_schema_extra=_topic(SPEECH)
    )
    asr_window_s: float = Field(
        0.0,
        description="Shortest encoder window, 1-30 s; 0: the recogniser's 15 s.",
        json_schema_extra=_topic(SPEECH),
    )
    asr_beams: int = Field(
        0, description="Beam width, 1-16; 0: the recogniser's 4.", json_schema_extra=_topic(SPEECH)
    )
    asr_preload: bool = Field(
        True,
        description="Load the speech model at start, in the background (off: on first use, "
        "which then waits about a second).",
        json_schema_extra=_topic(SPEECH),
    )
    recognizer: Literal["server", "browser", "auto"] = Field(
        "auto",
        description="The page's default recogniser.",
        json_schema_extra=_topic(SPEECH),
    )
    tile_url: str = Field(
        DEFAULT_TILE_URL,
        description="Outdoor map tiles, fetched by the browser (Leaflet template: {z}/{x}/{y}, "
        "{s} subdomains); empty: the plain local grid. docs/map.md.",
        json_schema_extra=_topic(SPEECH),
    )
    # -- TLS -----------------------------------------------------------------------------------
    tls: bool = Field(
        True,
        description="HTTPS on a non-loopback host (a local CA unless cert/key are set).",
        json_schema_extra=_topic(TLS),
    )
    cert: Path | None = Field(
        None, description="TLS certificate (PEM).", json_schema_extra=_topic(TLS)
    )
    key: Path | None = Field(
        None, description="Its private key (PEM).", json_schema_extra=_topic(TLS)
    )
    # -- MAVLink -------------------------------------------------------------------------------
    mavlink_sim_port: int = Field(
        5760, description="TCP port of the simulated PX4.", json_schema_extra=_topic(MAVLINK)
    )
    mavlink_key: str | None = Field(
        None,
        description="MAVLink 2 signing secret, 64 hex digits: sign everything, accept only "
        "signed frames.",
        json_schema_extra=_topic(MAVLINK),
    )
    # -- the bus (Zenoh; docs/bus.md) ---------------------------------------------------------
    bus_listen: CommaList = Field(
        (),
        description="Endpoints the console's bus router listens on; unset: where it listened "
        "last (DATA/bus/listen/CONSOLE, so the vehicles of a console that crashed find the one "
        "restarted in its place), else tcp/127.0.0.1:7447; the next free port if that is taken.",
        json_schema_extra=_topic(BUS),
    )
    bus_connect: CommaList = Field(
        (),
        description="Other bus routers to join (consoles on other hosts, zenohd); for a "
        "vehicle process, the routers it joins as vehicle-NAME with its vehicle key.",
        json_schema_extra=_topic(BUS),
    )
    bus_tls: Literal["auto", "on", "off"] = Field(
        "auto",
        description="TLS on the bus router's endpoints (tls/), with a certificate from the "
        "console's local CA; auto: on when it listens off loopback (docs/bus.md#tls).",
        json_schema_extra=_topic(BUS),
    )
    bus_ca: Path | None = Field(
        None,
        description="The CA file a tls/ bus router that a vehicle or a console joins is "
        "verified with (another console's tls/ca.pem); unset: the data directory's tls/ca.pem.",
        json_schema_extra=_topic(BUS),
    )
    bus_credentials: Path | None = Field(
        None,
        description="Another console's bus/credentials.txt: this console's bus takes its users "
        "and passwords (the consoles of a fleet share them), its own vehicle keys excepted.",
        json_schema_extra=_topic(BUS),
    )
    fleet_name: str = Field(
        "default",
        description="The fleet's name on the bus (its keys).",
        json_schema_extra=_topic(BUS),
    )
    console_name: str | None = Field(
        None,
        pattern=r"^[A-Za-z0-9_-]{1,64}$",  # one key segment (drone/bus/keys.py)
        description="This console's name on the bus, unique in the fleet; the central role "
        "goes to the lowest name alive when nobody holds it. Unset: HOST-PORT.",
        json_schema_extra=_topic(BUS),
    )
    central_grace_s: float = Field(
        60.0,
        gt=0,
        description="A vehicle flying a plan keeps flying it this long while no console holds "
        "the central role, then flies home (docs/failover.md).",
        json_schema_extra=_topic(BUS),
    )
    # -- vehicle processes ---------------------------------------------------------------------
    vehicles: Literal["inline", "process"] = Field(
        "process",
        description="Where each drone's flight stack runs, AR.Drone or MAVLink: its own "
        "supervised process, or inline in the web process.",
        json_schema_extra=_topic(VEHICLES),
    )
    vehicle_nice: int = Field(
        -10,
        description="Niceness a vehicle process asks for (where permitted).",
        json_schema_extra=_topic(VEHICLES),
    )
    control_rt_priority: int = Field(
        10,
        description="SCHED_FIFO priority of the 100 Hz control thread (where permitted; 0: off). "
        "Below the kernel's threaded interrupt handlers (50).",
        json_schema_extra=_topic(VEHICLES),
    )
    vehicle_rt_priority: int = Field(
        5,
        description="SCHED_RR priority of a vehicle's other threads (0: off); below "
        "control_rt_priority.",
        json_schema_extra=_topic(VEHICLES),
    )
    # -- flight recorder -----------------------------------------------------------------------
    recorder: bool = Field(
        True, description="Record every flight to MCAP.", json_schema_extra=_topic(RECORDER)
    )
    recordings_dir: Path | None = Field(
        None, description="Unset: data_dir/flights.", json_schema_extra=_topic(RECORDER)
    )
    recorder_budget_mb: float = Field(
        2048.0,
        description="Disk budget; the oldest recordings go first, never the current.",
        json_schema_extra=_topic(RECORDER),
    )
    recorder_chunk_s: float = Field(
        2.0,
        description="A finished chunk reaches the disk at least this often.",
        json_schema_extra=_topic(RECORDER),
    )
    recorder_idle_s: float = Field(
        30.0,
        description="Landed with no command this long: the flight session ends.",
        json_schema_extra=_topic(RECORDER),
    )
    recorder_preroll_s: float = Field(
        10.0,
        description="Seconds before a session's start kept in its recording.",
        json_schema_extra=_topic(RECORDER),
    )

    def __init__(self, **values: Any) -> None:
        try:
            super().__init__(**values)
        except ValidationError as exc:
            raise SettingsError.of(exc) from None

    @field_validator(
        "data_dir", "grammar_dir", "model_dir", "asr_model", "cert", "key", "recordings_dir"
    )
    @classmethod
    def _expand(cls, value: Path | None) -> Path | None:
        return value.expanduser() if value is not None else None

    @field_validator("tile_url")
    @classmethod
    def _tile_url(cls, value: str) -> str:
        return check_tile_url(value)

    @model_validator(mode="after")
    def _check(self) -> Settings:
        for name in ("control_rt_priority", "vehicle_rt_priority"):
            value = getattr(self, name)
            if not 0 <= value <= 99:  # sched_get_priority_max(SCHED_FIFO) on Linux
                raise ValueError(f"{name} must be 0 (off) to 99, not {value}")
        if 0 < self.control_rt_priority <= self.vehicle_rt_priority:
            raise ValueError(
                f"control_rt_priority ({self.control_rt_priority}) must be above "
                f"vehicle_rt_priority ({self.vehicle_rt_priority}): the vehicle's other threads "
                "would otherwise hold the control thread off the CPU"
            )
        for name in ("confidence_threshold", "confirm_floor"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"{name} must be 0 to 1, not {getattr(self, name)}")
        if self.asr_window_s != 0 and not 1 <= self.asr_window_s <= 30:
            raise ValueError(
                f"asr_window_s must be 0 (default) or 1 to 30, not {self.asr_window_s}"
            )
        try:
            check_deadline_s(self.command_deadline_s)
        except ValueError as exc:
            raise ValueError(f"command_deadline_s: {exc}") from exc
        if not 0 <= self.asr_beams <= 16:
            raise ValueError(f"asr_beams must be 0 (default) or 1 to 16, not {self.asr_beams}")
        if not self.temperature_warn_c < self.temperature_land_c:
            raise ValueError(
                f"temperature_warn_c ({self.temperature_warn_c}) must be below "
                f"temperature_land_c ({self.temperature_land_c}): the warning comes first"
            )
        return self

    def with_(self, **changes: Any) -> Settings:
        """A copy with ``changes`` applied and validated (the environment is not read again)."""
        try:
            return type(self).model_validate({**self.model_dump(), **changes})
        except ValidationError as exc:
            raise SettingsError.of(exc) from None

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None, **overrides: Any) -> Settings:
        """Read ``UAVC_<FIELD>`` variables (the process's, or ``env``), then apply the
        ``overrides`` that are not None (flags left unset)."""
        given = {k: v for k, v in overrides.items() if v is not None}
        if env is None:
            return cls(**given)
        source = EnvSettingsSource(cls, case_sensitive=False, env_prefix=ENV_PREFIX)
        source.env_vars = {k.lower(): v for k, v in env.items()}
        try:
            return cls.model_validate({**source(), **given})
        except ValidationError as exc:
            raise SettingsError.of(exc) from None


def describe(exc: ValidationError) -> str:
    """One line per refused setting, naming its variable and what was wrong."""
    lines = []
    for err in exc.errors():
        name = str(err["loc"][0]) if err["loc"] else ""
        ctx = err.get("ctx") or {}
        if err["type"] == "value_error" and "error" in ctx:
            lines.append(str(ctx["error"]))
            continue
        field = Settings.model_fields.get(name)
        if err["type"] == "literal_error" and field is not None:
            choices = [str(a) for a in field.annotation.__args__]  # type: ignore[union-attr]
            allowed = ", ".join(choices[:-1]) + " or " + choices[-1]
            lines.append(f"{name} must be {allowed}, not {err['input']!r}")
            continue
        kind = getattr(field.annotation, "__name__", str(field.annotation)) if field else "value"
        lines.append(
            f"{ENV_PREFIX}{name.upper()}={err['input']!r} is not a valid {kind}: {err['msg']}"
        )
    return "; ".join(lines)


def markdown() -> str:
    """``docs/configuration.md``: every setting by topic, its variable, flag, type, default and
    meaning."""
    out = [
        "# Configuration",
        "",
        "Generated from `server/settings.py` by `python -m server.settings > "
        "docs/configuration.md`; a test fails when it is stale.",
        "",
        "Every setting is an environment variable `UAVC_<NAME>` and a flag of `uav-console serve`",
        "and `uav-console vehicle` (`--help` lists them by the topics below); a flag wins over the",
        "environment, which wins over the default. Values are checked once at start; a bad one",
        "stops the program (exit status 2) with a line naming it. Lists are comma-separated in",
        "the environment and one or more values after their flag (`--bus-connect A B`,",
        "or the flag repeated).",
        "",
        "Two variables are not settings: `serve` hands them to each vehicle process it starts,",
        "in the environment, never on a command line: `UAVC_VEHICLE_KEY` (the vehicle's own key,",
        "else `--key-file`) and `UAVC_DOOR_SECRET` (hex: the secret its safety door checks",
        "the page's tickets with).",
    ]
    groups: dict[str, list[str]] = {}
    for name in Settings.model_fields:
        groups.setdefault(group_of(name), []).append(name)
    for group, names in groups.items():
        out += ["", f"## {group[0].upper()}{group[1:]}", ""]
        out += ["| variable | flag | type | default | meaning |", "|---|---|---|---|---|"]
        for name in names:
            field = Settings.model_fields[name]
            kind = _type_name(name)
            if name == "data_dir":
                default = "`~/.local/share/uav-console`"
            elif field.default_factory is not None:
                default = "(the shipped data)"
            else:
                default = "unset" if field.default in (None, ()) else f"`{_plain(field.default)}`"
            flags = " ".join(f"`{f}`" for f in flags_of(name))
            desc = (field.description or "").replace("|", "\\|")
            out.append(f"| `{ENV_PREFIX}{name.upper()}` | {flags} | {kind} | {default} | {desc} |")
    return "\n".join(out) + "\n"


@dataclass(frozen=True)
class Shape:
    """What a setting's annotation says about its values, for its flag and its docs line."""

    kind: type  # of one value: bool, int, float, str or Path
    optional: bool  # unset (None) is a value
    choices: tuple[str, ...]  # a Literal's values, else ()
    many: bool  # a list (a tuple of ``kind``)


def shape_of(name: str) -> Shape:
    """The :class:`Shape` of setting ``name``, read from its annotation."""
    annotation = Settings.model_fields[name].annotation
    args = [a for a in get_args(annotation) if a is not type(None)]
    optional = get_origin(annotation) in (Union, UnionType) and len(args) < len(
        get_args(annotation)
    )
    if optional:
        (annotation,) = args
    origin = get_origin(annotation)
    if origin is Literal:
        return Shape(str, optional, tuple(str(a) for a in get_args(annotation)), False)
    if origin is tuple:
        return Shape(get_args(annotation)[0], optional, (), True)
    assert isinstance(annotation, type), (name, annotation)
    return Shape(annotation, optional, (), False)


def _type_name(name: str) -> str:
    shape = shape_of(name)
    if shape.choices:
        return " \\| ".join(shape.choices)
    if shape.many:
        return "list"
    return "path" if shape.kind is Path else shape.kind.__name__


def _plain(value: Any) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, tuple):
        return ",".join(value)
    return str(value)


if __name__ == "__main__":
    print(markdown(), end="")
