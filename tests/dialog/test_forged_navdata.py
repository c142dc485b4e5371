"""Issue 14, closed loop: a forged navdata packet (battery 3 %, sequence far ahead) while the
drone hovers at a healthy battery. Before, the ANS landed it and the driver dropped the real
packets after the forgery as stale. Now the drone keeps flying and is still heard; a real
battery collapse still lands it once consistent packets confirm it. Lockstep, real task
manager, vehicle, ANS and the driver's protocol against the simulator."""

from __future__ import annotations

import pytest

from drone.ardrone.navdata import CtrlState, Demo, Navdata, encode_navdata
from server.dialog.states import State
from tests.dialog.lockstep_dialog import dialog_rig


@pytest.mark.timeout(120)
async def test_forged_battery_packet_does_not_land_the_drone() -> None:
    r = dialog_rig(seed=5)
    rig, dm, replies = r.rig, r.dm, r.replies
    assert rig.wait_link()
    assert (await dm.handle_utterance("take off")).accepted
    assert rig.run_until(lambda: dm.state is State.AIRBORNE_IDLE, 15.0), dm.state
    rig.run(2.0)
    proto, vehicle = rig.links[0].protocol, rig.vehicle
    assert proto.latest is not None and proto.latest.demo is not None
    healthy = proto.latest.demo.battery_pct
    assert healthy > 50

    forged = Navdata(
        state=proto.latest.state,
        sequence=proto.latest.sequence + 100_000,
        demo=Demo(ctrl_state=CtrlState.HOVERING << 16, battery_pct=3),
    )
    before = len(replies)  # (early navdata may raise its own alarm: issue 13, not this one)
    for ev in proto.receive_navdata(encode_navdata(forged), rig.clock.now()):
        vehicle.on_driver_event(ev)
    rig.run(3.0)
    assert dm.state is State.AIRBORNE_IDLE, dm.state
    assert not [r for r in replies[before:] if "critical" in r["text"].lower()]
    assert proto.latest.sequence < forged.sequence  # real packets still accepted
    assert vehicle.snapshot().link_ok

    # a real collapse of the battery is believed after consistent packets, and lands it
    rig.sim.physics.battery.drain_to(5.0)
    assert rig.run_until(lambda: dm.state in (State.LANDING, State.LANDED), 5.0), dm.state
    assert [r for r in replies[before:] if "critical" in r["text"].lower()]
