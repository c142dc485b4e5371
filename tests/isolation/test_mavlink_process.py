"""MAVLink drones fly in their own process too (issue 14): ``serve --vehicles process --drone
sim-mavlink`` spawns a vehicle that starts and owns the simulated PX4 (on 127.0.79.20:5760 here),
drives it over TCP, and joins the web process over ``/vehicle-link``; a mixed fleet
(``--drone sim,sim-mavlink``) puts each drone, AR.Drone and PX4, in a process of its own.

The test reads the vehicle's process, its sockets and the simulator's ground truth (through the
REST route the vehicle answers) — never a flight stack inside the web process.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from websockets.sync.client import connect

from tests.isolation.conftest import Served, serve, wait_for

pytestmark = pytest.mark.timeout(180)
HOST = "127.0.79.1"
PX4_PORT = 5760


def _cmdline(pid: int) -> list[str]:
    return Path(f"/proc/{pid}/cmdline").read_bytes().decode().split("\0")


def _ppid(pid: int) -> int:
    stat = Path(f"/proc/{pid}/stat").read_text()
    return int(stat.rsplit(")", 1)[1].split()[1])  # after "pid (comm)": state, ppid


def _listener_inode(addr: str, port: int) -> str:
    """The inode of the TCP socket listening on ``addr:port`` (``/proc/net/tcp``)."""
    a = "".join(f"{int(b):02X}" for b in reversed(addr.split(".")))
    want = f"{a}:{port:04X}"
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        cols = line.split()
        if cols[1] == want and cols[3] == "0A":  # LISTEN
            return cols[9]
    raise AssertionError(f"nothing listens on {addr}:{port}")


def _owns_socket(pid: int, inode: str) -> bool:
    fd_dir = Path(f"/proc/{pid}/fd")
    return any(os.readlink(fd_dir / fd) == f"socket:[{inode}]" for fd in os.listdir(fd_dir))


def _assert_own_process(srv: Served, name: str, kind: str, px4: str | None) -> int:
    """``name``'s flight stack runs in a child of ``serve`` given its own ``--drone`` entry;
    ``px4``: the address of the simulated PX4 that child listens on."""
    pid = int(srv.wait_vehicle(name)["pid"])
    assert pid != srv.proc.pid and _ppid(pid) == srv.proc.pid
    argv = _cmdline(pid)
    assert "vehicle" in argv and argv[argv.index("--name") + 1] == name
    assert argv[argv.index("--drone") + 1] == kind
    if px4 is not None:
        inode = _listener_inode(px4, PX4_PORT)
        assert _owns_socket(pid, inode), "the simulated PX4 is not the vehicle's"
        assert not _owns_socket(srv.proc.pid, inode)
    return pid


def test_a_simulated_px4_flies_in_its_own_process(tmp_path: Path) -> None:
    env = {"UAVC_SIM_BASE_ADDR": "127.0.79.20", "UAVC_SIM_SPEED": "4"}
    extra = ("--vehicles", "process", "--world", "outdoor")
    with serve(tmp_path, "sim-mavlink", extra=extra, env=env, host=HOST) as srv:
        _assert_own_process(srv, "uav1", "sim-mavlink", "127.0.79.20")
        assert "flight stacks: uav1 in its own process" in srv.log_path.read_text()
        d = srv.drone()
        assert d["vehicle"]["mode"] == "process" and d["simulated"]
        assert d["extra"]["protocol"] == "mavlink" and d["extra"]["autopilot"] == "PX4"

        r = srv.http.post("/api/v1/drones/uav1/takeoff")
        assert r.status_code == 200 and r.json()["accepted"], r.text
        wait_for(
            lambda: (s := srv.drone())["flying"] and s["ctrl_state"] in ("HOVERING", "FLYING"),
            "the PX4 to take off",
            30,
        )
        truth = srv.http.get("/api/v1/sim/uav1/truth").json()
        assert truth["z"] > 0.5, truth
        # its MAVROS topics cross the link: /mavros/state (latched) says armed
        with connect(srv.ws) as ws:
            sub = {"op": "subscribe", "topic": "/mavros/state", "type": "mavros_msgs/State"}
            ws.send(json.dumps(sub))

            def armed() -> bool:
                msg = json.loads(ws.recv(timeout=5))
                return bool(msg.get("topic") == "/mavros/state" and msg["msg"]["armed"])

            wait_for(armed, "/mavros/state armed", 15, period=0)

        r = srv.http.post("/api/v1/drones/uav1/land")
        assert r.status_code == 200 and r.json()["accepted"], r.text
        wait_for(
            lambda: not (s := srv.drone())["flying"] and s["ctrl_state"] == "LANDED",
            "the PX4 to land",
            40,
        )
        assert srv.http.get("/api/v1/sim/uav1/truth").json()["z"] < 0.1


def test_a_mixed_fleet_flies_each_drone_in_its_own_process(tmp_path: Path) -> None:
    env = {"UAVC_SIM_BASE_ADDR": "127.0.79.30"}
    extra = ("--vehicles", "process", "--world", "outdoor", "--fleet", "2")
    with serve(tmp_path, "sim,sim-mavlink", extra=extra, env=env, host=HOST) as srv:
        ardrone = _assert_own_process(srv, "uav1", "sim", None)
        px4 = _assert_own_process(srv, "uav2", "sim-mavlink", "127.0.79.31")
        assert ardrone != px4
        assert "flight stacks: uav1, uav2 each in its own process" in srv.log_path.read_text()
        assert "protocol" not in srv.drone("uav1")["extra"]
        assert srv.drone("uav2")["extra"]["protocol"] == "mavlink"
