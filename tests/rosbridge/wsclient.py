"""A bare rosbridge client on ``websockets`` for tests that need exact frames."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from typing import Any

from websockets.asyncio.client import ClientConnection, connect


class RawClient:
    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.seen: list[Any] = []

    @classmethod
    async def open(cls, url: str, **kw: Any) -> RawClient:
        ws = await connect(url, max_size=None, ping_interval=None, **kw)
        return cls(ws)

    async def send(self, obj: dict[str, Any] | str | bytes) -> None:
        await self.ws.send(obj if isinstance(obj, str | bytes) else json.dumps(obj))

    async def recv(self, timeout: float = 5.0) -> Any:
        raw = await asyncio.wait_for(self.ws.recv(), timeout)
        msg = raw if isinstance(raw, bytes) else json.loads(raw)
        self.seen.append(msg)
        return msg

    async def expect(
        self, pred: Callable[[Any], bool], timeout: float = 5.0, what: str = "frame"
    ) -> Any:
        """The next frame for which ``pred`` holds (others are kept in ``seen``)."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            left = deadline - loop.time()
            if left <= 0:
                raise AssertionError(f"no {what} within {timeout} s; seen {self.seen[-5:]!r}")
            try:
                msg = await self.recv(left)
            except TimeoutError:
                continue
            if pred(msg):
                return msg

    async def expect_op(self, op: str, timeout: float = 5.0, **fields: Any) -> dict[str, Any]:
        def pred(m: Any) -> bool:
            return (
                isinstance(m, dict)
                and m.get("op") == op
                and all(m.get(k) == v for k, v in fields.items())
            )

        result: dict[str, Any] = await self.expect(pred, timeout, f"{op} {fields}")
        return result

    async def status(self, id: str | None = None, timeout: float = 5.0) -> dict[str, Any]:
        if id is None:
            return await self.expect_op("status", timeout)
        return await self.expect_op("status", timeout, id=id)

    async def close(self) -> None:
        await self.ws.close()

    async def __aenter__(self) -> RawClient:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()
