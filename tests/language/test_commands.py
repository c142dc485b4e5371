"""The typed commands (drone/commands.py): the flat JSON objects of DESIGN §4 and the union
read from them round-trip unchanged, every command the project's grammars produce is in the
union, and anything else raises ``InvalidCommand`` with a sentence that names the slot."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drone.commands import (
    ACTIONS,
    DIRECTIONS,
    PATROL_CONTROLS,
    QUERY_ITEMS,
    SIDES,
    Goto,
    InvalidCommand,
    Move,
    Waypoints,
    parse_command,
    wire,
)
from server.language.nlu import default_nlu
from server.tasks.build import build_task
from server.tasks.errors import CommandError

LABELLED = Path(__file__).resolve().parents[1] / "data" / "nlu_labelled.jsonl"

# Numbers as the NLU writes them: an int when whole, else a float; both must survive.
numbers = st.one_of(
    st.integers(min_value=0, max_value=10_000),
    st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False),
)
ids = st.integers(min_value=0, max_value=1000)
words = st.text(alphabet="abcdefghijklmnopqrstuvwxyz ", min_size=1, max_size=12).filter(
    lambda s: s.strip() != ""
)


def _command(action: str, **slots: st.SearchStrategy[Any]) -> st.SearchStrategy[dict[str, Any]]:
    """A command of ``action`` with any subset of ``slots`` stated (unstated: omitted)."""
    return st.fixed_dictionaries({"action": st.just(action)}, optional=slots)


waypoint = st.one_of(
    st.fixed_dictionaries(
        {"x": numbers, "y": numbers}, optional={"z": numbers, "yaw_deg": numbers}
    ),
    st.fixed_dictionaries(
        {"lat": numbers, "lon": numbers}, optional={"alt": numbers, "yaw_deg": numbers}
    ),
)
commands = st.one_of(
    *(
        _command(a)
        for a in (
            "takeoff",
            "land",
            "hover",
            "emergency",
            "return_home",
            "describe",
            "cancel",
            "help",
            "search",
            *PATROL_CONTROLS,
        )
    ),
    _command("move", direction=st.sampled_from(DIRECTIONS), distance=numbers),
    _command(
        "turn",
        direction=st.sampled_from(SIDES),
        angle=numbers,
        object=words,
        colour=words,
        which=words,
    ),
    _command("goto", marker=ids, waypoint=ids, object=words, colour=words, which=words),
    _command(
        "patrol",
        markers=st.lists(ids, min_size=1, max_size=8),
        waypoints=st.lists(ids, min_size=1, max_size=8),
    ),
    _command("query", item=st.sampled_from(QUERY_ITEMS)),
    _command("choose", which=words, colour=words, object=words),
    st.fixed_dictionaries(
        {"action": st.just("waypoints"), "waypoints": st.lists(waypoint, min_size=1, max_size=5)},
        optional={"loop": st.booleans(), "tolerance_m": numbers, "yaw_deg": numbers},
    ),
)


# Generation time depends on the machine's load, not on the code: no health check on it.
@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(commands)
def test_a_command_round_trips_to_the_same_json(obj: dict[str, Any]) -> None:
    cmd = parse_command(obj)
    assert cmd.action == obj["action"]
    assert wire(cmd) == obj
    # byte for byte as the page sees it: an int stays an int, a float a float
    assert json.dumps(wire(cmd), sort_keys=True) == json.dumps(obj, sort_keys=True)
    assert parse_command(wire(cmd)) == cmd
    assert parse_command(cmd) is cmd


@settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(st.text(max_size=8), st.none() | st.integers() | st.text(max_size=8)))
def test_any_object_parses_or_raises_invalid_command(obj: dict[str, Any]) -> None:
    try:
        cmd = parse_command(obj)
    except InvalidCommand as exc:
        assert str(exc)
    else:
        assert wire(cmd) == {k: v for k, v in obj.items() if v is not None}


def test_every_action_the_union_holds_is_generated_above() -> None:
    assert {
        "takeoff",
        "land",
        "hover",
        "emergency",
        "return_home",
        "describe",
        "cancel",
        "help",
        "search",
        "move",
        "turn",
        "goto",
        "patrol",
        "query",
        "choose",
        "waypoints",
        *PATROL_CONTROLS,
    } == ACTIONS


def test_every_command_the_grammars_produce_is_in_the_union() -> None:
    """The labelled utterances of tests/data (what the page gets for each) and what the NLU
    says for them now: each command parses and writes back unchanged."""
    nlu = default_nlu()
    seen: set[str] = set()
    for line in LABELLED.read_text().splitlines():
        case = json.loads(line)
        for obj in case["commands"] + nlu.interpret(case["text"]):
            assert wire(parse_command(obj)) == obj, case["text"]
            seen.add(obj["action"])
    assert {"move", "turn", "goto", "patrol", "query", "takeoff", "land"} <= seen


def test_the_grammars_rules_name_only_actions_of_the_union() -> None:
    grammar = default_nlu().grammar
    assert {r.action for r in grammar.rules} <= ACTIONS


def test_interpretation_gives_typed_commands() -> None:
    interp = default_nlu().parse("take off and fly forward 2 meters then go to marker 3")
    assert interp.typed_commands() == [
        parse_command({"action": "takeoff"}),
        Move(direction="forward", distance=2),
        Goto(marker=3),
    ]


@pytest.mark.parametrize(
    ("obj", "why"),
    [
        ("land", "a command must be an object, got str"),
        ({}, "unknown action None"),
        ({"action": "fly_to_the_moon"}, "unknown action 'fly_to_the_moon'"),
        ({"action": "move", "direction": "sideways"}, "'move' needs 'direction' in forward"),
        ({"action": "move", "distance": True}, "'distance' must be a finite number, got True"),
        ({"action": "move", "distance": "2"}, "'distance' must be a finite number, got '2'"),
        ({"action": "turn", "direction": "up"}, "'turn' needs 'direction' left or right"),
        ({"action": "goto", "marker": 3.5}, "a marker id must be an integer, got 3.5"),
        ({"action": "goto", "object": " "}, "'object' must be a non-empty string"),
        ({"action": "patrol", "markers": []}, "'patrol' needs 'markers', a non-empty list"),
        ({"action": "query", "item": "mood"}, "'query' needs 'item' in battery"),
        ({"action": "land", "speed": 3}, "'land' has no slot 'speed'"),
        ({"action": "waypoints"}, "'waypoints' needs 'waypoints'"),
        ({"action": "waypoints", "waypoints": [{"x": 1}]}, "a waypoint needs 'y'"),
        ({"action": "waypoints", "waypoints": [{"lat": 1}]}, "a lat/lon waypoint needs 'lon'"),
        ({"action": "waypoints", "waypoints": [7]}, "waypoint 0 must be an object, got 7"),
    ],
)
def test_a_bad_command_says_what_is_wrong(obj: object, why: str) -> None:
    with pytest.raises(InvalidCommand, match=f"^{why}"):
        parse_command(obj)
    with pytest.raises(CommandError, match=f"^{why}"):
        build_task(obj)


def test_the_task_keeps_the_command_as_said() -> None:
    obj = {"action": "waypoints", "waypoints": [{"x": 1, "y": 2.5}], "tolerance_m": 0.5}
    task = build_task(obj)
    assert task.command == obj
    assert build_task(Waypoints.model_validate(obj)).command == obj


def test_the_task_manager_takes_typed_commands_as_their_json() -> None:
    from drone.sim.world import load_world
    from tests.autonomy.flight import Flight

    def flight() -> Flight:
        return Flight.make(load_world("indoor"), seed=3, camera=False, starts=[(4.0, 2.0, 0.0)])

    typed = flight().tm.submit([parse_command({"action": "takeoff"}), Move(direction="up")])
    as_json = flight().tm.submit([{"action": "takeoff"}, {"action": "move", "direction": "up"}])
    assert all(d.accepted for d in typed)
    assert [(d.command, d.accepted) for d in typed] == [(d.command, d.accepted) for d in as_json]
    assert typed[1].command == {"action": "move", "direction": "up"}
