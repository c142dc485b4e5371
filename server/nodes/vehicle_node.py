"""``VehicleNode``: one vehicle on the graph (DESIGN §4 "Graph"), ardrone_autonomy-compatible.

Publishes (a fleet prefixes ``/NAME``, e.g. ``/uav2/ardrone/navdata``):

- ``/ardrone/navdata`` (ardrone_autonomy/Navdata) at the navdata rate, converted as
  ardrone_autonomy does: state = major ctrl_state, rotX = phi/1000, rotY = −theta/1000,
  rotZ = −psi/1000 (degrees), altd mm, vx, vy = −vy, vz = −vz (mm/s), tm µs;
- ``/ardrone/navdata_gps`` (ardrone_autonomy/navdata_gps) in a world with a GPS origin: the
  navdata's GPS option field for field, once per new fix and at least every second while the
  option comes (the option repeats the receiver's last fix in every navdata packet);
- ``/ardrone/image_raw/compressed`` (sensor_msgs/CompressedImage): JPEG of the camera with the
  tracking overlay, at most ``image_hz`` (15); ``data`` is the JPEG's ``bytes``, as the graph
  carries ``uint8[]`` (a rosbridge client's JSON gets it as base64, encoded for the clients
  subscribed: server/rosbridge/values.py);
- ``/uav/pose`` (geometry_msgs/PoseStamped, frame ``map``): the EKF estimate, per navdata;
- ``/uav/markers`` (uav_console/MarkerArray): per processed frame, each detected marker's map
  pose and its distance from the drone;
- ``/uav/task`` (uav_console/TaskStatus, latched): whenever the status changes.

Subscribes: ``/cmd_vel`` (Twist fractions → ``vehicle.jog``, which cancels the running task);
``/ardrone/takeoff``, ``/ardrone/land``, ``/ardrone/reset`` (std_msgs/Empty). ``reset`` only
leaves the emergency state (unlike ardrone_autonomy it never cuts flying motors).

Deadlines (drone/deadline.py): a ``/cmd_vel`` jog, take-off or reset published with an
``issued`` time (:attr:`Graph.issued`) that reaches this node past ``command_deadline_s`` is
dropped, said on ``/console/reply`` and audited; ``/ardrone/land`` and a ``/cmd_vel`` of zeros
(the end of a jog) are stops and never expire.

Operator watchdog (DESIGN §5): while jogging, if neither ``/cmd_vel`` nor
``operator_heartbeat()`` is heard for ``heartbeat_timeout_s`` (1 s), the drone hovers.

Driving: real time ``await node.start()`` runs ``step`` at 20 Hz (task manager, watchdog,
status) and the JPEG stream in an asyncio task (encoding in a worker thread); lockstep calls
``node.step(now)`` (e.g. ``rig.add_stepper(lambda now, dt: node.step(now))``), which also
encodes the image when one is due.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Callable
from typing import Any

import cv2

from drone.ardrone.navdata import GPS_SIZE, TAG_GPS, Gps, Navdata, ros_navdata_fields
from drone.deadline import DEFAULT_DEADLINE_S, Deadline, Expired, ReportGate, label
from drone.perception.markers import FrameResult
from server.graph import Graph
from server.msgs import header
from server.vehicles import deadlines

log = logging.getLogger(__name__)

NAVDATA = "ardrone_autonomy/Navdata"
NAVDATA_GPS = "ardrone_autonomy/navdata_gps"
GPS_REPEAT_S = 1.0  # an unchanged fix is published again after this long
IMAGE = "sensor_msgs/CompressedImage"
POSE = "geometry_msgs/PoseStamped"
MARKERS = "uav_console/MarkerArray"
TASK = "uav_console/TaskStatus"
TWIST = "geometry_msgs/Twist"
EMPTY = "std_msgs/Empty"


def navdata_message(nav: Navdata, stamp_s: float, t_s: float) -> dict[str, Any]:
    """ardrone_autonomy/Navdata from a decoded packet (conversions in the module docstring)."""
    return {"header": header("ardrone_base_link", stamp_s), **ros_navdata_fields(nav, t_s * 1e6)}


def navdata_gps_message(gps: Gps, stamp_s: float) -> dict[str, Any]:
    """ardrone_autonomy/navdata_gps from a decoded GPS option (names as its navdata_gps.msg)."""
    g = gps
    return {
        "header": header("ardrone_base_link", stamp_s),
        "tag": TAG_GPS,
        "size": GPS_SIZE,
        "latitude": g.latitude_deg,
        "longitude": g.longitude_deg,
        "elevation": g.elevation_m,
        "hdop": g.hdop,
        "data_available": g.data_available,
        "zero_validated": bool(g.zero_validated),
        "wpt_validated": bool(g.wpt_validated),
        "lat0": g.lat0_deg,
        "long0": g.long0_deg,
        "lat_fused": g.lat_fused_deg,
        "long_fused": g.long_fused_deg,
        "gps_state": g.gps_state,
        "X_traj": g.x_traj,
        "X_ref": g.x_ref,
        "Y_traj": g.y_traj,
        "Y_ref": g.y_ref,
        "theta_p": g.theta_p,
        "phi_p": g.phi_p,
        "theta_i": g.theta_i,
        "phi_i": g.phi_i,
        "theta_d": g.theta_d,
        "phi_d": g.phi_d,
        "vdop": g.vdop,
        "pdop": g.pdop,
        "speed": g.speed_m_s,
        "lastFrameTimestamp": g.last_frame_timestamp,
        "degree": g.degree,
        "degree_magnetic": g.degree_magnetic,
        "ehpe": g.ehpe_m,
        "ehve": g.ehve_m,
        "c_n0": g.c_n0,
        "nbsat": g.nbsat,
        "channels": [{"sat": sat, "c_n0": cn0} for sat, cn0 in g.channels],
        "is_gps_plugged": bool(g.is_gps_plugged),
        "ephemerisStatus": g.ephemeris_status,
        "vx_traj": g.vx_traj,
        "vy_traj": g.vy_traj,
        "firmwareStatus": g.firmware_status,
    }


def _quat_yaw(yaw: float) -> dict[str, float]:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


class VehicleNode:
    """See the module docstring.

    Args:
        graph: the process graph.
        vehicle: a ``drone.ardrone.vehicle.ARDroneVehicle`` (MavrosNode: a ``MavlinkVehicle``).
        task_manager: its ``server.tasks.TaskManager``.
        name: the drone's name (``uav1``), carried in ``/uav/task``.
        prefix: ``""`` for a single drone, ``"/uav2"`` in a fleet.
        clock: monotonic time for the watchdog and rates (the vehicle's clock by default).
        stamp: wall-clock seconds for message headers (``time.time``; lockstep may pass the
            virtual clock).
    """

    def __init__(
        self,
        graph: Graph,
        vehicle: Any,  # an ARDroneVehicle (a MavlinkVehicle in MavrosNode, its subclass)
        task_manager: Any,
        name: str,
        prefix: str = "",
        *,
        clock: Callable[[], float] | None = None,
        stamp: Callable[[], float] = time.time,
        heartbeat_timeout_s: float = 1.0,
        image_hz: float = 15.0,
        jpeg_quality: int = 80,
        audit: Any = None,
        command_deadline_s: float = DEFAULT_DEADLINE_S,
    ) -> None:
        self.graph = graph
        self.vehicle = vehicle
        self.tasks = task_manager
        self.name = name
        self.prefix = prefix.rstrip("/")
        self.clock = clock or vehicle.clock.now
        self.stamp = stamp
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.image_period_s = 1.0 / image_hz
        self.jpeg_quality = jpeg_quality
        self.owner = f"vehicle:{name}"
        self.deadline = Deadline(command_deadline_s)
        self._expiry_reports = ReportGate()  # a late jog at 10 Hz is said once every 2 s
        self.expired = 0  # topic commands dropped as late
        self.topic = {
            k: self._name(v)
            for k, v in {
                "navdata": "/ardrone/navdata",
                "navdata_gps": "/ardrone/navdata_gps",
                "image": "/ardrone/image_raw/compressed",
                "pose": "/uav/pose",
                "markers": "/uav/markers",
                "task": "/uav/task",
                "cmd_vel": "/cmd_vel",
                "takeoff": "/ardrone/takeoff",
                "land": "/ardrone/land",
                "reset": "/ardrone/reset",
            }.items()
        }
        self._jogging = False
        # server.store.AuditLog (or None): jogs and /ardrone/* commands are audited like buttons
        self.audit = audit
        self._last_operator: float | None = None
        self._last_task: tuple[Any, ...] | None = None
        self._last_image_t = -math.inf
        # a world with a GPS origin asks the drone for the GPS option (drone.vehicle)
        self.gps = getattr(getattr(vehicle, "world", None), "gps_origin", None) is not None
        self._last_gps: tuple[Gps, float] | None = None  # (published option, when)
        self._last_image_frame = -1
        # (frame count, JPEG) of the last image published; the MJPEG route serves it too
        self.latest_jpeg: tuple[int, bytes | None] = (-1, None)
        self.images_published = 0
        self.watchdog_hovers = 0
        self._subs: list[Any] = []
        self._closed = False
        self._tasks: list[asyncio.Task[None]] = []
        self._advertise()

    def _name(self, topic: str) -> str:
        return f"{self.prefix}{topic}"

    # ------------------------------------------------------------------ wiring
    def _advertise(self) -> None:
        g, o, t = self.graph, self.owner, self.topic
        g.advertise(t["navdata"], NAVDATA, owner=o)
        if self.gps:
            g.advertise(t["navdata_gps"], NAVDATA_GPS, owner=o)
        g.advertise(t["image"], IMAGE, owner=o)
        g.advertise(t["pose"], POSE, owner=o)
        g.advertise(t["markers"], MARKERS, owner=o)
        g.advertise(t["task"], TASK, latch=True, owner=o)
        self._subs = [
            g.subscribe(t["cmd_vel"], self._on_cmd_vel, type=TWIST, owner=o),
            g.subscribe(t["takeoff"], self._on_takeoff, type=EMPTY, owner=o),
            g.subscribe(t["land"], self._on_land, type=EMPTY, owner=o),
            g.subscribe(t["reset"], self._on_reset, type=EMPTY, owner=o),
        ]
        self.vehicle.add_navdata_listener(self._on_navdata)
        self.vehicle.add_result_listener(self._on_result)
        self.tasks.on_event(lambda _n: self._publish_task(force=True))
        self._publish_task(force=True)

    def close(self) -> None:
        """Unsubscribe and unadvertise (the vehicle keeps flying; stop it separately)."""
        self._closed = True
        for s in self._subs:
            s.close()
        self._subs = []
        for topic in ("navdata", "image", "pose", "markers", "task"):
            self.graph.unadvertise(self.topic[topic], self.owner)
        if self.gps:
            self.graph.unadvertise(self.topic["navdata_gps"], self.owner)

    # ------------------------------------------------------------------ inputs
    def operator_heartbeat(self) -> None:
        """The jogging operator is still there (the console pings while a key is held)."""
        self._last_operator = self.clock()

    def _late(self, kind: str) -> bool:
        """Whether the topic command being delivered (``kind``: drone/deadline.py) is past its
        deadline now, as it reaches the drone; a late one is said and audited (a late jog
        once every 2 s) and must be dropped."""
        issued = getattr(self.graph, "issued", None)
        if issued is None:
            return False
        verdict = self.deadline.judge(kind, issued, self.stamp())
        if not isinstance(verdict, Expired):
            self._expiry_reports.reset(kind)
            return False
        self.expired += 1
        if kind != "jog" or self._expiry_reports.allow(kind, self.clock()):
            deadlines.report_expired(
                self.graph,
                self.audit,
                label(kind),
                verdict,
                kind=kind,
                drone=self.name,
                prefix=self.prefix,
                source="topic",
            )
        return True

    def _on_cmd_vel(self, msg: dict[str, Any]) -> None:
        try:
            lin, ang = msg.get("linear") or {}, msg.get("angular") or {}
            vals = [float(lin.get("x", 0.0)), float(lin.get("y", 0.0)), float(lin.get("z", 0.0))]
            vals.append(float(ang.get("z", 0.0)))
        except (TypeError, ValueError, AttributeError) as exc:
            log.warning("%s: bad /cmd_vel %r: %s", self.name, msg, exc)
            return
        # A late jog is dropped (the operator watchdog hovers a drone left jogging); the
        # end of a jog is a stop and always goes through.
        if self._late("jog" if any(v != 0.0 for v in vals) else "hover"):
            return
        try:
            self.vehicle.jog(*vals)
        except (TypeError, ValueError, AttributeError) as exc:
            log.warning("%s: bad /cmd_vel %r: %s", self.name, msg, exc)
            return
        jogging = any(v != 0.0 for v in vals)
        if jogging != self._jogging:
            what = "jog started " + "/".join(f"{v:+.2f}" for v in vals) if jogging else "jog ended"
            self._audit("jog", what)
        self._jogging = jogging
        self._last_operator = self.clock()

    def _audit(self, action: str, outcome: str) -> None:
        """One audit row for a topic command (start and end of a jog, /ardrone/*)."""
        if self.audit is None:
            return
        try:
            # On the log's writer thread: a jog or a landing never waits for the fsync.
            write = getattr(self.audit, "append_later", self.audit.append)
            write(
                utterance="",
                commands=[{"action": action}],
                action="executed",
                outcome=outcome,
                role="pilot",  # only pilots may publish these topics (security.py)
                source="topic",
                drone=self.name,
            )
        except Exception as exc:  # an audit failure must never stop a jog or a landing
            log.error("%s: audit log write failed: %s", self.name, exc)

    def _on_takeoff(self, _msg: dict[str, Any]) -> None:
        if self._late("takeoff"):
            return
        self._audit("takeoff", "takeoff sent (/ardrone/takeoff)")
        self.tasks.cancel("take-off requested")
        self.vehicle.takeoff()

    def _on_land(self, _msg: dict[str, Any]) -> None:
        self.tasks.preempt("land")
        self._audit("land", "land sent (/ardrone/land)")

    def _on_reset(self, _msg: dict[str, Any]) -> None:
        if self._late("reset"):
            return
        self._audit("reset", "reset sent (/ardrone/reset)")
        self.tasks.cancel("reset requested")
        self.vehicle.reset()

    # ------------------------------------------------------------------ outputs
    def _on_navdata(self, nav: Navdata, now: float) -> None:
        if self._closed:
            return
        stamp = self.stamp()
        self.graph.publish(self.topic["navdata"], navdata_message(nav, stamp, now))
        if self.gps and nav.gps is not None:
            last = self._last_gps
            if last is None or last[0] != nav.gps or now - last[1] >= GPS_REPEAT_S:
                self._last_gps = (nav.gps, now)
                self.graph.publish(self.topic["navdata_gps"], navdata_gps_message(nav.gps, stamp))
        est = self.vehicle.estimate
        self.graph.publish(
            self.topic["pose"],
            {
                "header": header("map", stamp),
                "pose": {
                    "position": {"x": est.x, "y": est.y, "z": est.z},
                    "orientation": _quat_yaw(est.yaw_rad),
                },
            },
        )

    def _on_result(self, result: FrameResult) -> None:
        if self._closed:
            return
        markers = []
        loc = self.vehicle.localiser
        for det in result.detections:
            m = loc.markers.get(det.marker_id) if loc is not None else None
            if m is None:
                continue
            markers.append(
                {
                    "id": det.marker_id,
                    "pose": {
                        "position": {"x": m.position[0], "y": m.position[1], "z": m.position[2]},
                        "orientation": _quat_yaw(m.yaw_rad),
                    },
                    "distance": det.distance_m,
                }
            )
        self.graph.publish(
            self.topic["markers"], {"header": header("map", self.stamp()), "markers": markers}
        )

    def _publish_task(self, force: bool = False) -> None:
        if self._closed:
            return
        st = self.tasks.status
        key = (st.name, st.state, round(st.progress, 2), st.detail)
        if not force and key == self._last_task:
            return
        self._last_task = key
        msg = {"header": header("map", self.stamp()), **st.as_message(self.name)}
        self.graph.publish(self.topic["task"], msg)

    def encode_image(self) -> dict[str, Any] | None:
        """The latest frame with the overlay as a CompressedImage message (None: no new frame)."""
        count = self.vehicle.frames_seen
        if count == self._last_image_frame:
            return None
        status = self.tasks.status
        line = f"task: {status.name} {status.state} {status.detail}" if status.name else "idle"
        frame = self.vehicle.overlay((line,))
        if frame is None:
            return None
        ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, self.jpeg_quality])
        if not ok:
            return None
        self._last_image_frame = count
        jpeg = buf.tobytes()
        self.latest_jpeg = (count, jpeg)
        return {
            "header": header("ardrone_base_frontcam", self.stamp()),
            "format": "jpeg",
            "data": jpeg,
        }

    def _publish_image(self, msg: dict[str, Any] | None) -> None:
        if msg is not None:
            self.graph.publish(self.topic["image"], msg)
            self.images_published += 1

    # ------------------------------------------------------------------ stepping
    def step(self, now: float, *, images: bool = True) -> None:
        """Task manager, operator watchdog and task status; the image too when due."""
        self.tasks.step(now)
        if (
            self._jogging
            and self._last_operator is not None
            and now - self._last_operator > self.heartbeat_timeout_s
        ):
            log.warning(
                "%s: operator silent for %.1f s while jogging: hover",
                self.name,
                now - self._last_operator,
            )
            self._jogging = False
            self.watchdog_hovers += 1
            self.vehicle.hover()
        self._publish_task()
        if images and now - self._last_image_t >= self.image_period_s:
            self._last_image_t = now
            self._publish_image(self.encode_image())

    async def start(self, rate_hz: float = 20.0) -> None:
        """Real time: step at ``rate_hz`` and stream images, until :meth:`stop`."""
        self._tasks.append(asyncio.create_task(self._run(1.0 / rate_hz), name=f"{self.name}-node"))
        self._tasks.append(asyncio.create_task(self._images(), name=f"{self.name}-images"))

    async def stop(self) -> None:
        for t in self._tasks:
            t.cancel()
        for t in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await t
        self._tasks = []
        self.close()

    async def _run(self, period: float) -> None:
        while True:
            try:
                self.step(self.clock(), images=False)
            except Exception:
                log.exception("%s: node step failed", self.name)
            await asyncio.sleep(period)

    async def _images(self) -> None:
        while True:
            try:
                self._publish_image(await asyncio.to_thread(self.encode_image))
            except Exception:
                log.exception("%s: image encoding failed", self.name)
            await asyncio.sleep(self.image_period_s)
