"""``/rosout`` (``rosgraph_msgs/Log``): the console's log lines, alerts and task events.

ROS tools read a node's log from ``/rosout``, and Foxglove's Rosbridge connection decides
between ROS 1 and ROS 2 by the type of that topic (``rosgraph_msgs/Log`` is ROS 1), so the graph
always has it. What goes on it:

- log records of the ``uav_console``, ``server`` and ``drone`` loggers that pass their level
  (warnings and errors by default; the recorder's "disk full" among them);
- every ``/console/reply`` (info → INFO, warn → WARN, alert → ERROR): what the console told
  the operator, alerts included;
- task events: a drone's ``/uav/task`` when its task or its state changes.

Levels are rosgraph_msgs/Log's constants (DEBUG=1, INFO=2, WARN=4, ERROR=8, FATAL=16).
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from server import msgs
from server.graph import Graph, GraphError

TOPIC = "/rosout"
TYPE = "rosgraph_msgs/Log"
OWNER = "rosout"
DEBUG, INFO, WARN, ERROR, FATAL = 1, 2, 4, 8, 16
LOGGERS = ("uav_console", "server", "drone")
_REPLY_LEVELS = {"info": INFO, "warn": WARN, "alert": ERROR}


def log_level(levelno: int) -> int:
    """A Python logging level as a rosgraph_msgs/Log level."""
    if levelno >= logging.CRITICAL:
        return FATAL
    if levelno >= logging.ERROR:
        return ERROR
    if levelno >= logging.WARNING:
        return WARN
    if levelno >= logging.INFO:
        return INFO
    return DEBUG


def log_message(
    level: int, name: str, text: str, *, file: str = "", function: str = "", line: int = 0
) -> dict[str, Any]:
    return {
        "header": msgs.header(""),
        "level": level,
        "name": name,
        "msg": text,
        "file": file,
        "function": function,
        "line": max(0, line),
        "topics": [],
    }


class Rosout(logging.Handler):
    """Publishes log records and console events on ``/rosout``; :meth:`attach` / :meth:`detach`."""

    def __init__(self, graph: Graph) -> None:
        super().__init__(logging.NOTSET)
        self.graph = graph
        self._busy = threading.local()
        self._tasks: dict[str, tuple[Any, Any]] = {}
        self._remove_tap: Any = None

    def attach(self) -> None:
        self.graph.advertise(TOPIC, TYPE, owner=OWNER)
        for name in LOGGERS:
            logging.getLogger(name).addHandler(self)
        self._remove_tap = self.graph.add_tap(self._tap)

    def detach(self) -> None:
        for name in LOGGERS:
            logging.getLogger(name).removeHandler(self)
        if self._remove_tap is not None:
            self._remove_tap()
            self._remove_tap = None

    def _publish(self, msg: dict[str, Any]) -> None:
        if getattr(self._busy, "on", False):
            return  # a log line written while publishing one: do not loop
        self._busy.on = True
        try:
            self.graph.publish(TOPIC, msg, type=TYPE)
        except GraphError:
            pass  # /rosout taken by a client with another type: nothing to log it to
        finally:
            self._busy.on = False

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            if record.exc_info and record.exc_info[1] is not None:
                text += f" ({type(record.exc_info[1]).__name__}: {record.exc_info[1]})"
            self._publish(
                log_message(
                    log_level(record.levelno),
                    record.name,
                    text,
                    file=record.pathname,
                    function=record.funcName,
                    line=record.lineno,
                )
            )
        except Exception:
            self.handleError(record)

    def _tap(self, topic: str, type_name: str, msg: dict[str, Any]) -> None:
        if type_name == "uav_console/Reply":
            level = _REPLY_LEVELS.get(str(msg.get("level")), INFO)
            self._publish(log_message(level, "console", str(msg.get("text", ""))))
        elif type_name == "uav_console/TaskStatus":
            key = (msg.get("name"), msg.get("state"))
            if self._tasks.get(topic) == key:
                return
            self._tasks[topic] = key
            detail = f": {msg['detail']}" if msg.get("detail") else ""
            text = f"{msg.get('drone') or topic}: task {key[0]} {key[1]}{detail}"
            level = WARN if str(key[1]).lower() in ("failed", "aborted", "preempted") else INFO
            self._publish(log_message(level, "tasks", text))
