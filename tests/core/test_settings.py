"""The one Settings model: UAVC_* variables cast and checked once, and its generated page."""

from __future__ import annotations

from pathlib import Path

import pytest

from server.settings import ROOT, Settings, SettingsError, flags_of, markdown


def test_configuration_page_is_generated_from_the_model() -> None:
    page = (ROOT / "docs" / "configuration.md").read_text()
    assert page == markdown(), "stale: run `python -m server.settings > docs/configuration.md`"


def test_every_setting_is_documented() -> None:
    missing = [n for n, f in Settings.model_fields.items() if not f.description]
    assert missing == []


def test_variables_are_cast_from_text() -> None:
    s = Settings.from_env(
        {
            "UAVC_PORT": "9000",
            "UAVC_ALLOW_ORIGINS": "https://a.example, https://b.example",
            "UAVC_RECORDER": "no",
            "UAVC_DATA_DIR": "~/uavc-test",
            "UAVC_ALTITUDE_CEILING_M": "12.5",
        }
    )
    assert s.port == 9000
    assert s.allow_origins == ("https://a.example", "https://b.example")
    assert s.recorder is False
    assert s.data_dir == Path.home() / "uavc-test"
    assert s.altitude_ceiling_m == 12.5


def test_flags_win_over_the_environment_and_unset_flags_do_not() -> None:
    s = Settings.from_env({"UAVC_PORT": "9000", "UAVC_WORLD": "outdoor"}, port=8123, world=None)
    assert (s.port, s.world) == (8123, "outdoor")


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"UAVC_PORT": "eighty"}, "UAVC_PORT='eighty' is not a valid int"),
        ({"UAVC_RECORDER": "maybe"}, "UAVC_RECORDER='maybe' is not a valid bool"),
        ({"UAVC_VEHICLES": "threads"}, "vehicles must be inline or process, not 'threads'"),
        ({"UAVC_RECOGNIZER": "cloud"}, "recognizer must be server, browser or auto"),
        ({"UAVC_CONFIRM_FLOOR": "1.5"}, "confirm_floor must be 0 to 1, not 1.5"),
    ],
)
def test_a_bad_value_names_its_variable(env: dict[str, str], message: str) -> None:
    with pytest.raises(SettingsError, match=message):
        Settings.from_env(env)


def test_settings_are_frozen_and_copies_are_checked() -> None:
    s = Settings()
    with pytest.raises(ValueError):
        s.port = 1  # type: ignore[misc]
    assert s.with_(port=1).port == 1
    with pytest.raises(SettingsError, match="confirm_floor must be 0 to 1"):
        s.with_(confirm_floor=2.0)


def test_the_page_names_every_setting_with_its_flags() -> None:
    page = (ROOT / "docs" / "configuration.md").read_text()
    for name in Settings.model_fields:
        flags = " ".join(f"`{f}`" for f in flags_of(name))
        assert f"| `UAVC_{name.upper()}` | {flags} |" in page, name


# Where the process environment may be used outside the model: python -m server installs the
# clock speed before anything reads the clock (and writes it for the processes it starts);
# serve hands its vehicle processes their environment (settings, the vehicle key, the door
# secret); a vehicle reads those two hand-offs.
ENVIRON_READERS = {
    "server/__main__.py": 1,
    "server/cli.py": 1,
    "server/timewarp.py": 1,
    "server/vehicles/central.py": 1,
    "server/vehicles/main.py": 2,
    "drone/mavlink/simserver.py": 1,  # a line of help text printed for pymavlink users
}


def test_the_environment_is_read_once_by_the_model() -> None:
    """Settings are validated once at start and passed down: no ``os.environ`` or ``getenv``
    reading ``UAVC_*`` mid-function anywhere else in ``server/`` and ``drone/``."""
    found: dict[str, int] = {}
    for package in ("server", "drone"):
        for path in sorted((ROOT / package).rglob("*.py")):
            text = path.read_text()
            count = text.count("os.environ") + text.count("getenv(")
            if count:
                found[str(path.relative_to(ROOT))] = count
    assert found == ENVIRON_READERS
