"""The wheel carries the shipped data, and the console runs from a plain (non-editable) install.

The Docker image and ``pip install .`` both install the wheel, where the repository's
``grammars/``, ``worlds/``, ``web/`` and ``models/captioner/`` are not next to the code; this
builds the wheel, installs it into a fresh virtual environment and serves the console from it,
outside the checkout.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import sysconfig
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.support.loopback import bus_endpoint, free_port, fresh_address

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ("grammars", "worlds", "web", "models/captioner")
DOCKER_CONTEXT = ("pyproject.toml", "README.md", "server", "drone", *SHIPPED[:3], "models")
SIM_ADDR = fresh_address()
TOKEN = "packaging-test-token"
PIP = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]


def shipped_files() -> list[str]:
    return sorted(
        p.relative_to(ROOT).as_posix()
        for d in SHIPPED
        for p in (ROOT / d).rglob("*")
        if p.is_file() and "__pycache__" not in p.parts
    )


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Built from what docker/Dockerfile copies, in a scratch copy (no build/ in the checkout)."""
    src = tmp_path_factory.mktemp("src")
    for name in DOCKER_CONTEXT:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, src / name)
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [*PIP, "wheel", "--no-deps", "--no-build-isolation", "-w", str(out), str(src)],
        check=True,
        capture_output=True,
        timeout=300,
    )
    (whl,) = out.glob("uav_console-*.whl")
    return whl


@pytest.fixture(scope="module")
def venv(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv with the wheel installed; third-party packages come from the test venv."""
    v = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(v)], check=True)
    site = Path(
        subprocess.run(
            [
                str(v / "bin" / "python"),
                "-c",
                "import sysconfig; print(sysconfig.get_path('purelib'))",
            ],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()
    )
    # A plain path line: the test venv's own .pth files (its editable install) are not read.
    (site / "deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    subprocess.run(
        [
            *PIP,
            "--python",
            str(v / "bin" / "python"),
            "install",
            "--no-deps",
            "--no-index",
            str(wheel),
        ],
        check=True,
        capture_output=True,
        timeout=300,
    )
    return v


def test_wheel_has_every_shipped_file(wheel: Path) -> None:
    names = set(zipfile.ZipFile(wheel).namelist())
    prefix = "uav_console-0.1.0.data/data/share/uav-console/"
    missing = [f for f in shipped_files() if prefix + f not in names]
    assert not missing, f"add these to [tool.setuptools.data-files] in pyproject.toml: {missing}"
    assert "server/app.py" in names and "drone/share.py" in names


def run_in(venv: Path, code: str, cwd: Path) -> str:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "UAVC_MODEL_DIR")}
    done = subprocess.run(
        [str(venv / "bin" / "python"), "-c", code],
        cwd=cwd,
        env=env,
        check=True,
        capture_output=True,
        text=True,
        timeout=120,
    )
    return done.stdout


def test_installed_package_finds_its_data_outside_the_checkout(venv: Path, tmp_path: Path) -> None:
    out = run_in(
        venv,
        "import server, drone.share as s; from server.settings import Settings; st = Settings();"
        "print(server.__file__); print(st.grammar_dir); print(st.model_dir);"
        "print(s.share_dir('worlds')); print(s.share_dir('web'))",
        tmp_path,
    )
    code, *dirs = out.split()
    share = (venv / "share" / "uav-console").resolve()
    assert not Path(code).is_relative_to(ROOT), code  # the installed code, not the checkout
    assert [Path(d).resolve() for d in dirs] == [
        share / "grammars",
        share / "models" / "captioner",
        share / "worlds",
        share / "web",
    ]


@pytest.fixture
def installed_server(venv: Path, tmp_path: Path) -> Iterator[str]:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "UAVC_MODEL_DIR")}
    env.update(UAVC_SIM_BASE_ADDR=SIM_ADDR, UAVC_DATA_DIR=str(tmp_path))
    env.setdefault("UAVC_VEHICLES", "inline")  # packaging, not isolation (tests/isolation)
    env.setdefault("UAVC_BUS_LISTEN", bus_endpoint())  # a bus router off 7447
    log = (tmp_path / "server.log").open("wb")
    cmd = [str(venv / "bin" / "uav-console"), "serve", "--port", str(port), "--token", TOKEN]
    proc = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and proc.poll() is None:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(f"{base}/api/v1/health", timeout=1).status_code == 200:
                    break
            time.sleep(0.2)
        assert proc.poll() is None, (tmp_path / "server.log").read_text()
        yield base
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


def test_installed_console_serves_page_grammars_world_and_captioner(installed_server: str) -> None:
    base, auth = installed_server, {"Authorization": f"Bearer {TOKEN}"}
    health = httpx.get(f"{base}/api/v1/health", timeout=10).json()
    assert health["captioner"] == "ready", health
    page = httpx.get(f"{base}/?token={TOKEN}", timeout=10)
    assert page.status_code == 200 and "<html" in page.text.lower()
    assert httpx.get(f"{base}/static/js/app.js", timeout=10).status_code == 200
    said = httpx.post(
        f"{base}/api/v1/interpret", json={"text": "take off"}, headers=auth, timeout=10
    ).json()
    assert [c["action"] for c in said["commands"]] == ["takeoff"], said
    world = httpx.get(f"{base}/api/v1/world", headers=auth, timeout=10).json()
    assert len(world["markers"]) == 12
