"""A real uvicorn server with the rosbridge router on a free loopback port, in a thread."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Coroutine, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from fastapi import FastAPI

from server.graph import Graph
from server.http.security import Security, TokenStore
from server.http.ws_guard import preauth_capped_ws
from server.rosbridge.context import BridgeContext
from server.rosbridge.endpoint import make_router
from server.settings import Settings
from tests.support.loopback import bound_socket
from tests.support.servers import threaded_server

T = TypeVar("T")


@dataclass
class RunningServer:
    port: int
    graph: Graph
    ctx: BridgeContext
    pilot: str
    observer: str
    loop: asyncio.AbstractEventLoop
    host: str = "127.0.0.1"

    def url(self, token: str | None = "pilot", path: str = "/rosbridge") -> str:
        tok = {"pilot": self.pilot, "observer": self.observer}.get(token or "", token)
        query = f"?token={tok}" if tok else ""
        return f"ws://{self.host}:{self.port}{path}{query}"

    def run(self, coro: Coroutine[Any, Any, T], timeout: float = 10.0) -> T:
        """Run ``coro`` on the server's loop (graph calls) and wait for its result."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(timeout)

    def call(self, fn: Any, *args: Any) -> Any:
        """Run a plain function on the server's loop thread and return its result."""

        async def wrapper() -> Any:
            return fn(*args)

        return self.run(wrapper())


@contextlib.contextmanager
def running_server(
    tmp: Path, *, ws: str | type[Any] | None = None, **ctx_overrides: Any
) -> Iterator[RunningServer]:
    """``ws``: uvicorn's WebSocket implementation; by default the one ``serve`` uses (the
    transport's pre-auth frame cap, ``server.http.ws_guard``)."""
    settings_overrides = {
        k: ctx_overrides.pop(k) for k in list(ctx_overrides) if k in Settings.model_fields
    }
    host = str(settings_overrides.pop("host", "127.0.0.1"))
    sock = bound_socket(host)
    settings = Settings(host=host, port=sock.getsockname()[1], data_dir=tmp, **settings_overrides)
    graph = Graph()
    tokens = TokenStore(tmp)
    ctx = BridgeContext(graph=graph, security=Security(settings, tokens), settings=settings)
    for k, v in ctx_overrides.items():
        setattr(ctx, k, v)
    loop_box: list[asyncio.AbstractEventLoop] = []

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        loop = asyncio.get_running_loop()
        graph.bind_loop(loop)
        loop_box.append(loop)
        yield

    app = FastAPI(lifespan=lifespan)
    app.include_router(make_router(ctx))
    try:
        with threaded_server(
            app,
            sock=sock,
            ws_max_size=4 * settings.max_frame_bytes,
            ws=ws or preauth_capped_ws(ctx.preauth_max_bytes),
            timeout_graceful_shutdown=1,
        ) as served:
            yield RunningServer(
                served.port,
                graph,
                ctx,
                tokens.pilot_token,
                tokens.observer_token,
                loop_box[0],
                host,
            )
    finally:
        ctx.close()
