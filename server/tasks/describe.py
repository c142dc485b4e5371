"""Describe the view: the captioner's sentence for what the camera sees."""

from __future__ import annotations

from server.tasks.base import Context, Outcome, PlanState, Task
from server.tasks.errors import RefusedError


class DescribeTask(Task):
    """Hands the current view to the describe hook (the captioner) and reports its sentence."""

    name = "describe"

    def plan(self, p: PlanState, ctx: Context) -> PlanState:
        if ctx.describe_hook is None:
            raise RefusedError("I can't describe the view: no captioner is loaded.")
        return p

    def start(self, ctx: Context, now: float) -> Outcome | None:
        super().start(ctx, now)
        assert ctx.describe_hook is not None
        try:
            text = ctx.describe_hook(ctx.snapshot())
        except Exception as exc:  # the captioner failing must not kill the task manager
            return Outcome(False, f"describing failed: {exc}")
        return Outcome(True, text)
