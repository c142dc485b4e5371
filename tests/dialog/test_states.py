"""The SNS transition table: complete and strict."""

from __future__ import annotations

import pytest

from server.dialog.errors import IllegalTransition
from server.dialog.states import TRANSITIONS, State, next_state
from server.language.nlu import NLU


def test_transition_table_is_complete_and_strict() -> None:
    assert set(TRANSITIONS) == set(State)
    assert next_state(State.LANDED, "takeoff") is State.TAKING_OFF
    with pytest.raises(IllegalTransition) as exc:
        next_state(State.LANDED, "land")
    assert exc.value.reason == "I am already on the ground."
    # every state of the machine has its active grammars in states.xml
    assert set(NLU().grammar.states) == {s.value for s in State}
