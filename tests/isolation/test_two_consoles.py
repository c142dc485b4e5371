"""Two independent consoles on one machine: two real ``serve`` processes, each with its own
vehicle process and simulated drone, sharing the data directory as one user's two consoles do.

The second finds the first's simulator on the configured address and moves its own to the
next free one, saying so in one line; each flies its own drone; an address asked for with
``--sim-addr`` that is taken is refused in one line; a vehicle process whose simulator address
is taken anyway (another console started in between) says so in one line and is not restarted
in a loop. No traceback reaches the operator anywhere.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from drone.sim.server import SimPorts, in_use, sim_sockets
from server.vehicles.keys import new_key
from tests.e2e.served import ROOT, serve
from tests.support.loopback import fresh_address

BASE = fresh_address(3)  # BASE, NEXT and FREE
NEXT = BASE.rsplit(".", 1)[0] + "." + str(int(BASE.rsplit(".", 1)[1]) + 1)
FREE = BASE.rsplit(".", 1)[0] + "." + str(int(BASE.rsplit(".", 1)[1]) + 2)


def listening(addr: str) -> bool:
    return in_use(addr, sim_sockets(SimPorts())) is not None


# serial: real consoles and vehicle processes on wall-clock deadlines (a command 2 s late
# is refused), which a second test run on the same 2 cores made them miss
@pytest.mark.serial
@pytest.mark.timeout(300)
def test_two_consoles_fly_their_own_drones(tmp_path: Path) -> None:
    data = tmp_path / "data"  # one user's data directory, shared by both consoles
    data.mkdir()
    env = {"UAVC_SIM_BASE_ADDR": BASE, "UAVC_VEHICLES": "process"}
    env["UAVC_ASR_PRELOAD"] = "false"  # typed commands only: no speech model loaded at start
    assert not listening(BASE) and not listening(NEXT)
    with serve([], data, token="first-pilot", env=env) as first:
        assert listening(BASE)
        with serve([], data, token="second-pilot", env=env) as second:
            assert listening(NEXT)
            note = (
                f"uav-console: the simulator address {BASE} is taken (UDP 5554 on {BASE} is in "
                f"use: another console?); this console's simulators are on {NEXT} "
                "(--sim-addr chooses)"
            )
            assert note in second.log().splitlines(), second.log()
            # each console flies its own drone, and only its own
            assert second.say("take off")["accepted"]
            second.wait_truth(lambda t: t["flying"] and t["z"] > 0.5, 30, "second airborne")
            assert not first.truth()["flying"]
            assert first.say("take off")["accepted"]
            first.wait_truth(lambda t: t["flying"] and t["z"] > 0.5, 30, "first airborne")
            assert second.say("land")["accepted"]
            second.wait_truth(lambda t: not t["flying"], 30, "second landed")
            assert first.truth()["flying"]
            assert first.say("land")["accepted"]
            first.wait_truth(lambda t: not t["flying"], 30, "first landed")

            # an address asked for that is taken: argparse's usage and one error line, before
            # anything starts (port 1: never reached)
            asked = subprocess.run(
                [sys.executable, "-m", "server", "serve", "--sim-addr", BASE, "--port", "1"],
                cwd=ROOT,
                env={**os.environ, "UAVC_DATA_DIR": str(data)},
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert asked.returncode == 2 and asked.stdout == "", asked
            assert asked.stderr.splitlines()[-1] == (
                f"uav-console serve: error: the simulator address {BASE} is taken (UDP 5554 on "
                f"{BASE} is in use: another console?); choose another with --sim-addr; e.g. "
                f"--sim-addr {FREE} is free"
            )

            # a vehicle whose simulator address was taken between the look and the start
            bus = first.http.get("/api/v1/health").json()["bus"]["endpoints"][0]
            argv = [sys.executable, "-m", "server", "vehicle", "--name", "uav1", "--index", "0"]
            vehicle = subprocess.run(
                [*argv, "--bus-connect", bus, "--world", "indoor"],
                cwd=ROOT,
                env={
                    **os.environ,
                    "UAVC_SIM_BASE_ADDR": BASE,
                    "UAVC_TOKEN": "first-pilot",
                    "UAVC_VEHICLE_KEY": new_key(),  # a vehicle joins with its own key
                },
                capture_output=True,
                text=True,
                timeout=60,
            )
            assert vehicle.returncode == 3, vehicle
            said = [line for line in vehicle.stderr.splitlines() if "uav-console vehicle:" in line]
            assert said == [
                f"uav-console vehicle: uav1: the simulator's UDP 5554 on {BASE} is in use "
                "(another console's simulator?); `serve --sim-addr` moves this console's "
                "simulators"
            ], vehicle.stderr
            assert "Traceback" not in vehicle.stderr

            # each console keeps its own vehicle's pid: neither takes the other's for an orphan
            pids = {p.relative_to(data).as_posix() for p in data.glob("vehicles/*/*.pid")}
            assert pids == {f"vehicles/{first.port}/uav1.pid", f"vehicles/{second.port}/uav1.pid"}
            assert second.http.get("/api/v1/health").json()["drones"] == {"uav1": True}
        for log in (first.log(), second.log()):
            assert "Traceback" not in log and "Address already in use" not in log, log
            assert "flight process stopped" not in log  # no vehicle died and restarted


def test_a_supervised_vehicle_that_cannot_start_is_not_restarted() -> None:
    """The supervisor's side: a child that exits with the cannot-start status is not started
    again, and the consoles are told once (a real child process, a real graph; no deadline on
    the wall clock, so it runs in the parallel stage)."""
    import asyncio
    from types import SimpleNamespace

    from server.graph import Graph
    from server.vehicles import names
    from server.vehicles.central import VehicleCentral, VehicleProcess

    graph = Graph()
    graph.advertise("/console/reply", "uav_console/Reply")
    replies: list[dict[str, object]] = []
    graph.subscribe("/console/reply", replies.append)
    central = VehicleCentral.__new__(VehicleCentral)  # only its supervision, no link endpoint
    central.runtime = SimpleNamespace(graph=graph)  # type: ignore[assignment]
    central.alerts, central._stopping = [], False
    code = f"import sys; sys.exit({names.EXIT_CANNOT_START})"
    vp = VehicleProcess([sys.executable, "-c", code], dict(os.environ), "uav1")

    async def run() -> None:
        graph.bind_loop(asyncio.get_running_loop())
        await vp.spawn()
        await asyncio.wait_for(central._supervise(vp), 10)

    asyncio.run(run())
    assert vp.starts == 1 and vp.exits == [names.EXIT_CANNOT_START]
    assert [r["text"] for r in replies] == [
        "uav1's flight process cannot start here; not restarting it."
    ]
    assert replies[0]["level"] == "alert"
