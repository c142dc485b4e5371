"""Errors of the dialog package.

DialogError
└── IllegalTransition   the SNS state machine has no transition for (state, event); the
                        dialog manager turns it into a spoken refusal with the reason
"""

from __future__ import annotations


class DialogError(Exception):
    """Base of the dialog package's errors."""


class IllegalTransition(DialogError):
    """No transition from ``state`` on ``event``; ``reason`` is a sentence for the operator."""

    def __init__(self, state: str, event: str, reason: str) -> None:
        super().__init__(f"no transition from {state} on {event}: {reason}")
        self.state = state
        self.event = event
        self.reason = reason
