"""Task types and the per-vehicle task manager (see ``server.tasks.manager`` for the API)."""

from server.tasks.manager import Decision, TaskManager, TaskNotice, TaskStatus
from server.tasks.states import TaskState

__all__ = ["Decision", "TaskManager", "TaskNotice", "TaskState", "TaskStatus"]
