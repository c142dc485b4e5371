"""MAVLink drones fly in their own process too (issue 14): ``serve --vehicles process --drone
sim-mavlink`` spawns a vehicle that starts and owns the simulated PX4, drives it over TCP, and
joins the web process over the bus; a mixed fleet (``--drone sim,sim-mavlink``) puts
each drone, AR.Drone and PX4, in a process of its own. (A single PX4 in its own process, flying,
is checked on the server of tests/isolation/test_mavlink_safety.py, which this file's helpers
serve too.)

The test reads the vehicle's process, its sockets and the simulator's ground truth (through the
REST route the vehicle answers) — never a flight stack inside the web process.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from drone.mavlink.simserver import TCP_PORT
from drone.sim.server import sim_endpoint
from tests.isolation.conftest import Served, serve
from tests.support.loopback import fresh_address

pytestmark = pytest.mark.timeout(180)
HOST = fresh_address()
PX4_PORT = TCP_PORT  # UAVC_MAVLINK_SIM_PORT's default: PX4 SITL's TCP port


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


def assert_own_process(srv: Served, name: str, kind: str, px4: str | None) -> int:
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


def test_a_mixed_fleet_flies_each_drone_in_its_own_process(tmp_path: Path) -> None:
    base = fresh_address(2)
    env = {"UAVC_SIM_BASE_ADDR": base}
    extra = ("--vehicles", "process", "--world", "outdoor", "--fleet", "2")
    with serve(tmp_path, "sim,sim-mavlink", extra=extra, env=env, host=HOST) as srv:
        ardrone = assert_own_process(srv, "uav1", "sim", None)
        px4 = assert_own_process(srv, "uav2", "sim-mavlink", sim_endpoint(1, base)[0])
        assert ardrone != px4
        assert "flight stacks: uav1, uav2 each in its own process" in srv.log_path.read_text()
        assert "protocol" not in srv.drone("uav1")["extra"]
        assert srv.drone("uav2")["extra"]["protocol"] == "mavlink"
