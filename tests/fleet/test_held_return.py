"""A drone flying home that its own safety holds in a hover (the vehicle's watch of a silent
central server) is sent home again once the CTM hears it: lockstep, the real simulator, task
managers, LTMs and CTM."""

from __future__ import annotations

from experiments.patrol import PatrolConfig, PatrolExperiment

FAST = {"flight_time_s": 150.0, "charge_pct_s": 1.0}


def test_a_drone_held_in_a_hover_on_its_way_home_is_sent_home_again() -> None:
    """The vehicle's watch of a silent central server preempts whatever the drone does with a
    hover (``VehicleHost._on_loss``). A drone flying home then hovered where it was until its
    battery ran out, off its pad (seen in a live console whose central was starved of CPU):
    its LTM said nothing (only a patrol plan's interruption was reported), so the CTM, which
    had sent the return, never sent it again."""
    exp = PatrolExperiment(PatrolConfig(drones=2, duration_s=200.0, **FAST))
    held: dict[str, float] = {}

    def hold(now: float) -> None:
        if held:
            return
        for i, name in enumerate(("uav1", "uav2")):
            rec = exp.ctm.drones.get(name)
            t = exp.rig.sims[i].truth
            if rec is not None and rec.role.value == "returning" and t.flying and t.z > 3.5:
                exp.tasks[i].preempt("hover", by="central server silent")
                held[name] = now

    exp.hooks.append(hold)
    report = exp.run()
    assert held, report.events
    name, t_held = next(iter(held.items()))
    i = int(name[3:]) - 1
    rows = [r for r in report.tracks[name] if r[0] > t_held - exp.rig.clock.now() + 200.0]
    landed = [r for r in rows if r[3] < 0.05]
    assert landed, rows[-5:]
    first = landed[0]  # (t, x, y, z, battery, role)
    pad = exp.ltms[i].station
    # landed on its pad with charge to spare, not where it was held with an empty battery
    assert abs(first[1] - pad.x) < 1.0 and abs(first[2] - pad.y) < 1.0, first
    assert first[4] > 10.0, first
    assert any(f"{name} held on its way home" in e for e in report.events), report.events
