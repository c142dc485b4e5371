"""Task types and the per-vehicle task manager (see ``server.tasks.manager`` for the API).

``base`` holds what every task is made of and ``legs`` the setpoint legs most are flown in;
one module per kind of task: ``flight`` (take off, land, emergency, hover), ``motion`` (move,
turn), ``goto``, ``patrol``, ``waypoints``, ``home`` (return home), ``search``, ``describe``,
``objects`` (the world's objects as targets); ``build`` is the table from command to task.
"""

from server.tasks.manager import Decision, TaskManager, TaskNotice, TaskStatus
from server.tasks.states import TaskState

__all__ = ["Decision", "TaskManager", "TaskNotice", "TaskState", "TaskStatus"]
