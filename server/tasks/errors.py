"""Exceptions of the task manager (server/tasks).

::

    TaskError
    ├── CommandError (ValueError)        a command dict that is not a valid DESIGN §4 command
    │   └── RefusedError                 valid, but cannot be done now (unknown marker, outside
    │                                    the room, not flying…); ``reason`` says why
    └── IllegalTransition (RuntimeError) a task state change the table in states.py forbids

``TaskManager.submit`` never raises for bad commands: it returns a refused ``Decision`` carrying
the reason; these exceptions are what the validators raise internally and what direct users of
the task classes see.
"""

from __future__ import annotations


class TaskError(Exception):
    """Base of every error raised by ``server.tasks``."""


class CommandError(TaskError, ValueError):
    """The command is malformed: unknown action, wrong slot type, value out of range."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class RefusedError(CommandError):
    """The command is well formed but cannot be carried out now."""


class IllegalTransition(TaskError, RuntimeError):
    """A task was asked to move between states the transition table does not allow."""
