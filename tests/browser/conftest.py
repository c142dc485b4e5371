"""Browser tests: the real server on the simulator, driven by Debian's headless Chromium.

The server runs as ``python -m server serve`` in a subprocess (exactly what an operator starts),
with its simulated drone on a loopback address of its own so it never clashes with other tests.
Chromium is launched with flags that keep it off the network; set ``UAVC_SKIP_BROWSER=1`` to
skip these tests on a machine without ``/usr/bin/chromium``.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.support.loopback import bus_endpoint, free_port, fresh_address

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = Path(os.environ.get("UAVC_CHROMIUM", "/usr/bin/chromium"))
# Flags that keep a headless Chromium off the network and quiet (no updates, sync, QUIC, GPU).
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
PILOT = "pilot-token-for-browser-tests"
OBSERVER = "observer-token-for-browser-tests"
START_TIMEOUT_S = 180.0  # a loaded 2-core machine: the imports alone can take a minute
SCREENSHOTS = ROOT / "docs" / "screenshots"
AXE = ROOT / "tests" / "node" / "node_modules" / "axe-core" / "axe.min.js"  # make node-deps
# The viewports the layout is checked at (CSS pixels): desktops, a tablet, a phone both ways.
SIZES = {
    "desktop": (1280, 800),
    "desktop-hd": (1920, 1080),
    "tablet": (820, 1180),
    "phone": (390, 844),
    "phone-landscape": (844, 390),
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    skip = os.environ.get("UAVC_SKIP_BROWSER") == "1"
    for item in items:
        if "tests/browser/" not in str(item.fspath).replace(os.sep, "/"):
            continue
        item.add_marker(pytest.mark.browser)
        if skip:
            item.add_marker(pytest.mark.skip(reason="UAVC_SKIP_BROWSER=1"))


@dataclass
class ServerProcess:
    """``uav-console serve`` on the simulator in a subprocess; restartable on the same port."""

    data_dir: Path
    sim_addr: str
    extra_args: tuple[str, ...] = ()
    # Settings of this server as UAVC_* variables (a shorter timeout than the default, say).
    env: dict[str, str] = field(default_factory=dict)
    port: int = field(default_factory=free_port)
    proc: subprocess.Popen[bytes] | None = None
    log_path: Path | None = None

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def url(self, token: str = PILOT) -> str:
        return f"{self.base}/?token={token}"

    def start(self) -> None:
        env = dict(os.environ)
        env.update(
            UAVC_SIM_BASE_ADDR=self.sim_addr,
            UAVC_DATA_DIR=str(self.data_dir),
            PYTHONUNBUFFERED="1",
        )
        env.update(self.env)
        # Console behaviour, not isolation: flight stacks inline unless UAVC_VEHICLES says
        # otherwise (serve defaults to process mode; tests/isolation covers it).
        env.setdefault("UAVC_VEHICLES", "inline")
        env.setdefault("UAVC_BUS_LISTEN", bus_endpoint())  # a bus router off 7447
        # Off the network: no map tiles unless a test serves its own (test_8_map.py).
        env.setdefault("UAVC_TILE_URL", "")
        self.log_path = self.data_dir / f"server-{self.port}.log"
        log = self.log_path.open("ab")
        cmd = [
            sys.executable,
            "-m",
            "server",
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--token",
            PILOT,
            "--observer-token",
            OBSERVER,
            "--data-dir",
            str(self.data_dir),
            "--seed",
            "1",
            *self.extra_args,
        ]
        self.proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
        log.close()
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log_tail()}")
            with contextlib.suppress(httpx.HTTPError, ValueError):
                r = httpx.get(f"{self.base}/api/v1/health", timeout=1.0)
                # and every drone linked: a vehicle process (UAVC_VEHICLES=process) joins
                # a few seconds after the server answers, and commands wait 3 s at most
                if r.status_code == 200 and all(r.json()["drones"].values()):
                    return
            time.sleep(0.2)
        self.stop()
        raise RuntimeError(
            f"server did not become healthy in {START_TIMEOUT_S} s:\n{self.log_tail()}"
        )

    def stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        self.proc = None

    def restart(self) -> None:
        self.stop()
        self.start()

    def log_tail(self, n: int = 4000) -> str:
        if self.log_path is None or not self.log_path.exists():
            return ""
        return self.log_path.read_text(errors="replace")[-n:]

    # -- REST helpers for ground truth and set-up --------------------------------------------
    def api(self, method: str, path: str, token: str = PILOT, **kw: Any) -> httpx.Response:
        return httpx.request(
            method,
            f"{self.base}/api/v1{path}",
            headers={"Authorization": f"Bearer {token}"},
            timeout=10.0,
            **kw,
        )

    def truth(self, drone: str = "uav1") -> dict[str, Any]:
        r = self.api("GET", f"/sim/{drone}/truth")
        r.raise_for_status()
        return dict(r.json())


def _server(
    tmp_path_factory: pytest.TempPathFactory,
    name: str,
    addr: str,
    *extra: str,
    env: dict[str, str] | None = None,
) -> Iterator[ServerProcess]:
    """A started server with ``extra`` arguments and ``env`` settings, stopped after."""
    if os.environ.get("UAVC_SKIP_BROWSER") == "1":
        pytest.skip("UAVC_SKIP_BROWSER=1")
    server = ServerProcess(tmp_path_factory.mktemp(name), addr, tuple(extra), dict(env or {}))
    server.start()
    try:
        yield server
    finally:
        server.stop()


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """The shared server (its drone starts landed; flying tests run in file order)."""
    yield from _server(tmp_path_factory, "uavc-browser", fresh_address())


@pytest.fixture
def own_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """A server of the test's own (for restarts)."""
    yield from _server(tmp_path_factory, "uavc-browser-own", fresh_address())


@pytest.fixture(scope="module")
def fleet_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """Two simulated drones: topics prefixed /uav1, /uav2; one per module (its tests leave both
    drones landed)."""
    yield from _server(tmp_path_factory, "uavc-browser-fleet", fresh_address(2), "--fleet", "2")


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is missing: apt-get install -y chromium (or UAVC_SKIP_BROWSER=1)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        # launch() gives every browser a fresh temporary user-data-dir of its own.
        b = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@dataclass
class ConsolePage:
    """A console page with everything it logged collected for assertions."""

    page: Any
    errors: list[str] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)
    failed_requests: list[str] = field(default_factory=list)

    def console_errors(self) -> list[str]:
        return list(self.errors)


def wait_ready(
    page: Any,
    *,
    lease: bool = False,
    frames: int = 0,
    world: bool = False,
    telemetry: bool = False,
    timeout_ms: int = 20_000,
) -> None:
    """Wait until the console page is ready for a test, in one condition: connected, and where
    asked holding the pilot lease, past ``frames`` camera frames, its map's world loaded and the
    drone's telemetry shown (the battery reads a percentage)."""
    conditions = ["document.querySelector('#conn')?.dataset.state === 'open'"]
    if lease:
        conditions.append("window.uavConsole?.haveLease === true")
    if frames:
        conditions.append(
            f"Number(document.querySelector('#camera').dataset.frames || 0) > {frames}"
        )
    if world:
        conditions.append("(window.uavConsole?.map?.world ?? null) !== null")
    if telemetry:
        conditions.append("(document.querySelector('#battery')?.textContent ?? '').includes('%')")
    page.wait_for_function(" && ".join(f"({c})" for c in conditions), timeout=timeout_ms)


def open_console(
    browser: Any,
    url: str,
    *,
    viewport: dict[str, int] | None = None,
    color_scheme: str = "light",
    init_script: str | None = None,
    lease: bool = False,
    frames: int = 0,
    world: bool = False,
    telemetry: bool = False,
) -> tuple[Any, ConsolePage]:
    """A fresh context (own storage) with the console loaded and ready (``wait_ready``)."""
    ctx = browser.new_context(
        viewport=viewport or {"width": 1440, "height": 900},
        color_scheme=color_scheme,
        device_scale_factor=1,
        service_workers="block",
        # The page's CSP has no 'unsafe-eval'; Playwright's string predicates need eval.
        # test_5_csp.py loads the page under its CSP and checks nothing is blocked.
        bypass_csp=True,
    )
    if init_script:
        ctx.add_init_script(init_script)
    page = ctx.new_page()
    cp = ConsolePage(page)

    def on_console(m: Any) -> None:
        cp.messages.append(f"{m.type}: {m.text}")
        if m.type == "error":
            cp.errors.append(m.text)

    page.on("console", on_console)
    page.on("pageerror", lambda e: cp.errors.append(f"pageerror: {e}"))
    page.on("requestfailed", lambda r: cp.failed_requests.append(f"{r.url} {r.failure}"))
    page.goto(url)
    wait_ready(page, lease=lease, frames=frames, world=world, telemetry=telemetry)
    return ctx, cp


@pytest.fixture(scope="module")
def console(browser: Any, server: ServerProcess) -> Iterator[ConsolePage]:
    """One pilot page on the shared server for the module's tests that use it (what it logged
    is kept for all of them). It holds the pilot lease from the first such test to the module's
    end: a test that needs the lease on a page of its own runs before the first one."""
    ctx, cp = open_console(browser, server.url(), lease=True)
    try:
        yield cp
    finally:
        ctx.close()
