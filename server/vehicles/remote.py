"""A drone whose stack runs in a vehicle process, as the web process sees it.

:class:`RemoteDroneStack` answers everything the REST routes ask of a
:class:`~server.runtime.DroneStack` (telemetry, direct actions, the latest JPEG, ground truth,
faults) from what the vehicle publishes over the link (``/NAME/vehicle/telemetry``, the camera
topic) and through its control service; :class:`RemoteDialog` answers ``POST /command`` through
the vehicle's own dialog manager. Nothing here blocks: a direct action is sent and answered at
once ("emergency sent"), as in-process.
"""

from __future__ import annotations

import asyncio
import base64
import concurrent.futures
import contextlib
import json
import logging
import math
import time
from typing import TYPE_CHECKING, Any, cast

from server.dialog.manager import DialogResult
from server.graph import Graph, GraphError, ServiceError
from server.msgs import header
from server.runtime import DroneStack
from server.vehicles import names

if TYPE_CHECKING:
    from drone.ardrone.driver import ARDroneDriver
    from drone.vehicle import Vehicle

log = logging.getLogger(__name__)

TELEMETRY_STALE_S = 1.0
CALL_TIMEOUT_S = 10.0


class _Frames:
    """What ``Runtime.describe`` reads of a driver: the latest camera frame (from the JPEG)."""

    def __init__(self, stack: RemoteDroneStack) -> None:
        self._stack = stack

    @property
    def latest_frame(self) -> Any:
        import cv2
        import numpy as np

        _, jpeg = self._stack.latest_jpeg()
        if jpeg is None:
            return None
        return cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)

    async def stop(self) -> None:
        """The vehicle process owns the driver."""


class _Remote:
    """Stand-in for parts that live in the vehicle process (stopping them is its job)."""

    async def stop(self, **_: Any) -> None:
        return None


class RemoteDroneStack(DroneStack):
    """See the module docstring; ``graph`` is the central graph."""

    def __init__(self, graph: Graph, name: str, prefix: str, *, simulated: bool = True) -> None:
        super().__init__(
            name,
            prefix,
            cast("Vehicle", _Remote()),
            cast("ARDroneDriver", None),
            sim=cast(Any, _Remote()) if simulated else None,
        )
        self.driver = cast("ARDroneDriver", _Frames(self))
        self.graph = graph
        self.info: dict[str, Any] = {}
        self.last: dict[str, Any] = {}
        self.last_t: float | None = None
        self._jpeg_b64: str | bytes | bytearray | None = None
        self._jpeg: tuple[int, bytes | None] = (-1, None)
        self._jpeg_count = 0
        self._pending: set[asyncio.Task[Any]] = set()
        self._subs = [
            graph.subscribe(names.telemetry_topic(name), self._on_telemetry, type=names.STRING),
            graph.subscribe(names.info_topic(name), self._on_info, type=names.STRING),
            graph.subscribe(
                f"{prefix}/ardrone/image_raw/compressed",
                self._on_image,
                type="sensor_msgs/CompressedImage",
            ),
        ]

    # ------------------------------------------------------------------ inputs
    def _on_telemetry(self, msg: dict[str, Any]) -> None:
        try:
            data = json.loads(str(msg.get("data", "")))
        except ValueError:
            log.warning("%s: bad telemetry message", self.name)
            return
        if isinstance(data, dict):
            self.last = data
            self.last_t = time.monotonic()

    def _on_info(self, msg: dict[str, Any]) -> None:
        try:
            data = json.loads(str(msg.get("data", "")))
        except ValueError:
            return
        if isinstance(data, dict):
            self.info = data
            if not data.get("simulated", True):
                self.sim = None

    def _on_image(self, msg: dict[str, Any]) -> None:
        data = msg.get("data")
        if isinstance(data, str | bytes | bytearray):  # the bridge may hand decoded bytes
            self._jpeg_b64 = data
            self._jpeg_count += 1

    # ------------------------------------------------------------------ DroneStack
    @property
    def connected(self) -> bool:
        return self.last_t is not None and time.monotonic() - self.last_t < TELEMETRY_STALE_S

    def link_ok(self) -> bool:
        return self.connected and bool(self.last.get("link_ok"))

    def telemetry(self) -> dict[str, Any]:
        out = {k: v for k, v in self.last.items() if k != "truth"}
        out.setdefault("link_ok", False)
        out["link_ok"] = self.link_ok()
        out["name"] = self.name
        out["simulated"] = self.sim is not None
        out["vehicle"] = {
            "mode": "process",
            "connected": self.connected,
            "pid": self.info.get("pid"),
            "safety_url": self.info.get("safety_url"),
            "age_s": None if self.last_t is None else round(time.monotonic() - self.last_t, 3),
        }
        return out

    def direct(self, action: str) -> str:
        self._send({"op": "direct", "action": action})
        return f"{action} sent"

    def latest_jpeg(self) -> tuple[int, bytes | None]:
        if self._jpeg[0] != self._jpeg_count and self._jpeg_b64 is not None:
            raw = self._jpeg_b64
            jpeg = base64.b64decode(raw) if isinstance(raw, str) else bytes(raw)
            self._jpeg = (self._jpeg_count, jpeg)
        return self._jpeg

    def truth(self) -> dict[str, Any]:
        """The simulator's ground truth, asked of the vehicle now (from a worker thread, as the
        sync REST route runs); on the loop itself, the last telemetry's (≤ 0.1 s old)."""
        out: dict[str, Any] | None = None
        if self._off_loop():
            with contextlib.suppress(GraphError, TimeoutError):
                out = dict(self._call_sync({"op": "truth"}))
        if out is None:
            out = dict(self.last.get("truth") or {})
        out["name"] = self.name
        return out

    def inject_fault(self, body: Any) -> None:
        """Apply a simulator fault in the vehicle (raises ``ValueError`` if it refuses)."""
        args: dict[str, Any] = {"op": "fault", "kind": body.kind}
        for key in ("duration_s", "battery_pct"):
            value = getattr(body, key, None)
            if value is not None:
                args[key] = float(value)
        if getattr(body, "wind_mps", None) is not None:
            args["wind_mps"] = [float(v) for v in body.wind_mps]
        if not self._off_loop():
            self._send(args)
            return
        try:
            self._call_sync(args)
        except ServiceError as exc:
            raise ValueError(str(exc).split(" failed: ", 1)[-1]) from exc

    def _off_loop(self) -> bool:
        try:
            asyncio.get_running_loop()
        except RuntimeError:
            return self.graph.loop is not None
        return False

    def _call_sync(self, args: dict[str, Any], timeout_s: float = 5.0) -> Any:
        """Call the control service from a worker thread and wait for the answer."""
        assert self.graph.loop is not None
        fut = asyncio.run_coroutine_threadsafe(self.call(args, timeout_s), self.graph.loop)
        try:
            return fut.result(timeout_s + 1.0)
        except concurrent.futures.TimeoutError as exc:
            fut.cancel()
            raise TimeoutError(f"{self.name} did not answer") from exc

    # ------------------------------------------------------------------ calls
    async def call(self, args: dict[str, Any], timeout_s: float = CALL_TIMEOUT_S) -> Any:
        """Call the vehicle's control service (raises ``GraphError`` if it is not there)."""
        return await self.graph.call_service(
            names.control_service(self.name), args, timeout=timeout_s
        )

    def _send(self, args: dict[str, Any]) -> None:
        """Send without waiting, from the loop or from a worker thread (sync REST routes)."""

        async def send() -> None:
            try:
                await self.call(args)
            except GraphError as exc:
                log.error("%s: %s not delivered: %s", self.name, args.get("op"), exc)

        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            loop = None
        if loop is None:
            target = self.graph.loop
            if target is None:
                raise RuntimeError("the graph has no event loop yet")
            asyncio.run_coroutine_threadsafe(send(), target)
            return
        task = loop.create_task(send())
        self._pending.add(task)
        task.add_done_callback(self._pending.discard)

    def close(self) -> None:
        for s in self._subs:
            s.close()
        self._subs = []


class RemoteDialog:
    """``runtime.dialogs[name]`` for a vehicle process: its dialog manager, over the link."""

    def __init__(self, stack: RemoteDroneStack) -> None:
        self.stack = stack

    def note_direct(self, action: str) -> None:
        """A button acted on the drone directly. The vehicle's own dialog manager follows
        the drone from its navdata within one ANS period; the web process keeps no state."""

    def announce(self, text: str, level: str = "info") -> None:
        """Say ``text`` to every console (a refused button), as the vehicle's dialog would."""
        msg = {
            "header": header(now=None),
            "text": f"{self.stack.name}: {text}" if self.stack.prefix else text,
            "level": level,
            "speak": True,
            "utterance": "",
            "commands": "[]",
        }
        self.stack.graph.publish("/console/reply", msg)

    async def handle_utterance(
        self, text: str, confidence: float = 1.0, source: str = "text", role: str = "pilot"
    ) -> DialogResult:
        args: dict[str, Any] = {"op": "utterance", "text": text, "source": source, "role": role}
        args["confidence"] = confidence if math.isfinite(confidence) else 0.0
        try:
            out = await self.stack.call(args)
        except GraphError as exc:
            return DialogResult(f"{self.stack.name} cannot be reached now ({exc}).", [], False)
        return DialogResult(
            str(out.get("reply", "")), list(out.get("commands") or []), bool(out.get("accepted"))
        )
