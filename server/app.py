"""The FastAPI application: REST under /api/v1, rosbridge at /rosbridge, the console at /."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, Request
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates

from drone.share import share_dir
from server import __version__
from server.api import drones, flights, language, sim, speech, strict, system, tls, tts
from server.api.deps import fleet_access, fleet_deadline
from server.api.models import add_command_schemas
from server.http.audit_trail import RestAuditMiddleware
from server.http.http_guard import HttpGuard, content_security_policy
from server.http.map_tiles import tile_source
from server.recorder import replay_live
from server.recorder.replay_live import ReplayHub
from server.runtime import Runtime
from server.settings import Settings
from server.vehicles.deadlines import RestCommandExpired
from server.vehicles.door import advertised_url
from server.vehicles.errors import VehicleUnavailable

WEB = share_dir("web")


def create_app(settings: Settings | None = None, *, announce: bool = False) -> FastAPI:
    """Build the app; drones, dialog and the rest start in the lifespan and stop with it.

    Args:
        settings: read once by the caller (``Settings.from_env()`` if None).
        announce: print the pilot's clickable URL at start-up (``uav-console serve``).
    """
    settings = settings or Settings.from_env()
    runtime = Runtime(settings)

    # Recorded flights replayed in the page, read-only, on graphs of their own.
    replays = ReplayHub(
        lambda: runtime.flight_index,
        runtime.recording_id,
        runtime.security,
        lambda: runtime.world.to_dict(),
    )

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await runtime.start()
        if announce:
            for line in runtime.announcement():
                print(line, file=sys.stderr if line.startswith(" ") else sys.stdout, flush=True)
        try:
            yield
        finally:
            await replays.close()
            await runtime.stop()

    app = FastAPI(
        title="uav-console",
        version=__version__,
        description="Operator console for autonomous drones. REST for scripts; the same "
        "topics and services are on the rosbridge v2 WebSocket at /rosbridge.",
        lifespan=lifespan,
    )
    app.state.runtime = runtime
    app.state.replays = replays
    # Intent/outcome audit rows of REST actions, inside the guard.
    app.add_middleware(RestAuditMiddleware, security=runtime.security, trail=runtime.trail)
    # Host allowlist, body limits before parsing, security headers, the token cookie.
    app.add_middleware(HttpGuard, security=runtime.security)
    strict.install(app)  # 422s that echo NaN or lone surrogates stay 422s
    add_command_schemas(app)  # /docs shows the commands' union

    @app.exception_handler(VehicleUnavailable)
    async def vehicle_unavailable(request: Request, exc: VehicleUnavailable) -> JSONResponse:
        # A drone whose flight process is starting, restarting or gone: not a missing drone
        # (404) and not a server fault (500); the caller may retry.
        body: dict[str, Any] = {"detail": str(exc), "retry_after_s": exc.retry_after_s}
        if exc.drone is not None:
            body["drone"] = exc.drone
        headers = {"Retry-After": str(exc.retry_after_s)}
        return JSONResponse(body, status_code=503, headers=headers)

    @app.exception_handler(RestCommandExpired)
    async def command_expired(request: Request, exc: RestCommandExpired) -> JSONResponse:
        # Not flown: the command reached us past its deadline (drone/deadline.py).
        body = {
            "accepted": False,
            "detail": exc.text,
            "expired": True,
            "age_s": round(exc.verdict.age_s, 3),
            "deadline_s": exc.verdict.deadline_s,
        }
        return JSONResponse(body, status_code=409)

    for router in (
        system.router,
        language.router,
        drones.router,
        sim.router,
        tts.router,
        flights.router,
    ):
        app.include_router(router, prefix="/api/v1")
    app.include_router(replay_live.router, prefix="/api/v1")
    for router in (speech.router, tls.router):  # speech, HTTPS for phones
        app.include_router(router, prefix="/api/v1")
    fleet_deps = [Depends(fleet_access), Depends(fleet_deadline)]
    app.include_router(runtime.fleet.router(dependencies=fleet_deps), prefix="/api/v1")
    for router in runtime.extra_routers():
        app.include_router(router)

    templates = Jinja2Templates(directory=str(WEB / "templates"))
    if (WEB / "static").is_dir():
        app.mount("/static", StaticFiles(directory=str(WEB / "static")), name="static")

    @app.get("/", response_class=HTMLResponse, include_in_schema=False)
    def console(request: Request) -> HTMLResponse:
        page = templates.TemplateResponse(
            request, "index.html", {"version": __version__, "settings": settings}
        )
        # The page connects to this origin and to the vehicles' safety doors, at the host this
        # request named (a phone on the LAN): its policy names exactly those doors.
        host = request.headers.get("host")
        doors = [advertised_url(url, host) for url in runtime.vehicles.door_urls()]
        # and the outdoor map's tiles, from the one tile host the operator set
        tiles = tile_source(settings.tile_url)
        csp = content_security_policy((d for d in doors if d), [tiles] if tiles else [])
        page.headers["content-security-policy"] = csp
        return page

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon() -> RedirectResponse:
        return RedirectResponse("/static/icons/favicon.svg")

    return app


def web_root() -> Path:
    return WEB
