"""The persistent-patrol experiment: the paper's mission flown in lockstep, measured, plotted.

``uav-console patrol --drones 2 --duration 3600`` builds a ``LockstepRig`` on the outdoor world
(real simulator, AR.Drone wire protocol in memory, EKF, the paper's PID, the task manager), one
LTM per drone, one CTM, and a station per drone that restores a landed drone (battery swap,
default 120 s, or charging at a rate: the world's pads then charge in the simulator). The
mission is the world's four waypoints (a 30 m square at 5 m near 36.367164 N, 127.363472 E)
given to the CTM as lat/lon/alt, as ``POST /missions`` would, with its handoff rule:
``predictive`` (the relief is on the route before the threshold) or ``reactive`` (the paper's:
the patrolling drone leaves at the threshold and the relief is sent then); ``--handoff both``
flies both on the same seed and reports them side by side. Coverage is measured from the
simulator's *true* positions: a drone covers the route while it flies (not in emergency) within
``corridor_m`` of the route at route height. The window starts when the route is first reached
(take-off and first transit are reported apart).

``config`` holds the knobs, ``run`` builds and flies the rig, ``metrics`` measures coverage,
gaps and revisits from the truth, ``report`` formats the figures, ``plot`` draws them
(matplotlib, the ``report`` extra) and ``cli`` is ``uav-console patrol``.
"""

from experiments.patrol.cli import patrol_main
from experiments.patrol.config import MAX_DRONES, PatrolConfig
from experiments.patrol.report import PatrolReport, compare_text
from experiments.patrol.run import LockstepLink, PatrolExperiment, StationService, run_patrol

__all__ = [
    "MAX_DRONES",
    "LockstepLink",
    "PatrolConfig",
    "PatrolExperiment",
    "PatrolReport",
    "StationService",
    "compare_text",
    "patrol_main",
    "run_patrol",
]
