"""``serve``'s and ``vehicle``'s setting flags, generated from the Settings model: one flag per
field, grouped by topic, a flag's value reaching Settings over the environment, and a bad value
refused by argparse with the flag named."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from server.cli import _parser, main, settings_from
from server.settings import ROOT, Settings, flags_of, group_of, shape_of

COMMANDS = ("serve", "vehicle")
NEEDS = {"serve": [], "vehicle": ["--name", "uav1"]}  # what each command cannot go without
# Values a setting's bounds or the model's checks refuse the generic choice for.
SPECIAL: dict[str, list[str]] = {"tile_url": [""], "mavlink_key": ["ab" * 32]}


def subparser(command: str) -> argparse.ArgumentParser:
    sub = next(a for a in _parser()._actions if isinstance(a, argparse._SubParsersAction))
    found = sub.choices[command]
    assert isinstance(found, argparse.ArgumentParser)
    return found


def flag_values(name: str, tmp: Path) -> tuple[list[str], Any]:
    """A flag of setting ``name`` with a value other than its default, and that value parsed."""
    field = Settings.model_fields[name]
    shape = shape_of(name)
    default = None if field.default_factory is not None else field.default
    flag = flags_of(name)[0]
    if name in SPECIAL:
        return [flag, *SPECIAL[name]], SPECIAL[name][0]
    if shape.kind is bool:
        return ([f"--no-{flag[2:]}"], False) if default else ([flag], True)
    if shape.choices:
        other = next(c for c in shape.choices if c != default)
        return [flag, other], other
    if shape.many:  # two values, then the flag again with a comma-separated one
        return [flag, "a", "b", flag, "c,d"], ("a", "b", "c", "d")
    if shape.kind is Path:
        return [flag, str(tmp / name)], tmp / name
    if shape.kind is int:
        value = 1 if default is None else default + 1
        return [flag, str(value)], value
    if shape.kind is float:
        number = 1.0 if not default else default + 0.25
        return [flag, str(number)], number
    return [flag, f"x{len(name)}"], f"x{len(name)}"


def env_text(value: Any) -> str:
    if isinstance(value, bool):
        return "1" if value else "0"
    if isinstance(value, tuple):
        return ",".join(value)
    return str(value)


@pytest.mark.parametrize("command", COMMANDS)
def test_every_setting_has_a_flag_in_its_topic(command: str) -> None:
    parser = subparser(command)
    for name, field in Settings.model_fields.items():
        group = next(g for g in parser._action_groups if g.title == f"settings: {group_of(name)}")
        [action] = [a for a in group._group_actions if a.dest == name]
        assert set(flags_of(name)) == set(action.option_strings), name
        assert action.default is None, f"{name}: its one default is the model's"
        assert field.description and field.description in (action.help or "").replace("%%", "%")
        assert f"UAVC_{name.upper()}" in (action.help or "")


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("name", list(Settings.model_fields))
def test_a_flag_reaches_settings_and_wins_over_the_environment(
    command: str, name: str, tmp_path: Path
) -> None:
    argv, expected = flag_values(name, tmp_path)
    args = _parser().parse_args([command, *NEEDS[command], *argv])
    field = Settings.model_fields[name]
    default = field.get_default(call_default_factory=True)
    env = {} if default is None else {f"UAVC_{name.upper()}": env_text(default)}
    assert Settings.from_env(env).model_dump()[name] == default  # the environment is read
    assert getattr(settings_from(args, env), name) == expected


@pytest.mark.parametrize("command", COMMANDS)
def test_unset_flags_leave_the_environment_then_the_model_default(command: str) -> None:
    args = _parser().parse_args([command, *NEEDS[command]])
    assert all(getattr(args, name) is None for name in Settings.model_fields)
    assert settings_from(args, {"UAVC_FLEET": "3"}).fleet == 3
    settings = settings_from(args, {})
    assert settings == Settings.from_env({})
    assert settings.world == Settings.model_fields["world"].default  # serve's and vehicle's
    assert settings.vehicles == "process"  # what `serve` runs, stated once, in the model


def test_older_flag_names_still_work() -> None:
    argv = ["serve", "--sim-addr", "127.0.0.7", "--allow-origin", "https://a.example"]
    argv += ["--allow-origin", "https://b.example", "--no-tls", "--no-camera"]
    argv += ["--bus-listen", "tcp/127.0.0.1:1", "--bus-listen", "tcp/127.0.0.1:2"]
    s = settings_from(_parser().parse_args(argv), {})
    assert s.sim_base_addr == "127.0.0.7"
    assert s.allow_origins == ("https://a.example", "https://b.example")
    assert (s.tls, s.camera) == (False, False)
    assert s.bus_listen == ("tcp/127.0.0.1:1", "tcp/127.0.0.1:2")
    sim = _parser().parse_args(["sim"])  # the simulator alone: the same defaults
    assert (sim.world, sim.speed) == (Settings().world, Settings().sim_speed)


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--port", "eighty"], "argument --port: 'eighty': Input should be a valid integer"),
        (["--fleet", "-1"], "argument --fleet: '-1': Input should be greater than or equal to 0"),
        (["--clock-speed", "0"], "argument --clock-speed: '0': Input should be greater than 0"),
        (["--recognizer", "cloud"], "argument --recognizer: invalid choice: 'cloud'"),
        (["--console-name", "a b"], "argument --console-name: 'a b': String should match"),
        (["--data-dir"], "argument --data-dir: expected one argument"),
        (["--no-camera=1"], "argument --camera/--no-camera: ignored explicit argument '1'"),
    ],
)
def test_a_bad_flag_value_is_an_argparse_error_naming_the_flag(
    command: str, argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_:
        main([command, *NEEDS[command], *argv])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert f"uav-console {command}: error: {message}" in err, err


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--confirm-floor", "1.5"], "confirm_floor must be 0 to 1, not 1.5 (given as "),
        (["--tile-url", "ftp://tiles"], "http:// or https://, not 'ftp://tiles' (given as "),
        (["--control-rt-priority", "5"], "--control-rt-priority, --vehicle-rt-priority)"),
    ],
)
def test_values_the_model_refuses_exit_2_naming_the_flag(
    command: str, argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """Checks on a whole setting or across settings run when the model is built, before
    anything starts; the message names the flags that gave the values it refuses."""
    assert main([command, *NEEDS[command], *argv, "--vehicle-rt-priority", "5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"uav-console {command}: error: ")
    assert message in err, err
    assert f"(given as {argv[0]}" in err


def test_a_bad_flag_in_a_real_process_exits_2_with_one_line(tmp_path: Path) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "server", "serve", "--port", "eighty", "--data-dir", str(tmp_path)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2
    assert "uav-console serve: error: argument --port: 'eighty'" in out.stderr
    assert not any(tmp_path.iterdir()), "nothing started"


@pytest.mark.parametrize("command", COMMANDS)
def test_help_lists_the_settings_by_topic(command: str) -> None:
    out = subprocess.run(
        [sys.executable, "-m", "server", command, "--help"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    for name in Settings.model_fields:
        assert f"settings: {group_of(name)}:" in out.stdout
        assert all(flag in out.stdout for flag in flags_of(name)), name
    if command == "vehicle":
        assert "--key-file" in out.stdout and "--bus-connect" in out.stdout
