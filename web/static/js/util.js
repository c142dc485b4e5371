// Small shared helpers: topic names per drone, message conversions, formatting.

/** Topics that belong to one drone get the fleet prefix (/uav2/...); console topics do not. */
export function droneTopic(name, drone, fleet) {
  return fleet && drone ? `/${drone}${name}` : name;
}

/** Yaw (rad, counter-clockwise from +x, REP 103) of a geometry_msgs/Quaternion. */
export function quaternionYaw(q) {
  if (!q) return 0;
  const { x = 0, y = 0, z = 0, w = 1 } = q;
  return Math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z));
}

/** Seconds since the epoch of a header stamp ({sec, nanosec} or ROS 1 {secs, nsecs}). */
export function stampSeconds(stamp) {
  if (!stamp) return null;
  const sec = stamp.sec ?? stamp.secs;
  const nsec = stamp.nanosec ?? stamp.nsecs ?? 0;
  if (typeof sec !== "number" || sec <= 0) return null;
  return sec + nsec / 1e9;
}

// ardrone_autonomy Navdata.state (AutonomyLab/ardrone_autonomy msg/Navdata.msg).
export const CTRL_STATES = Object.freeze({
  0: "Unknown",
  1: "Inited",
  2: "Landed",
  3: "Flying",
  4: "Hovering",
  5: "Test",
  6: "Taking off",
  7: "Flying",
  8: "Landing",
  9: "Looping",
});

export function ctrlStateName(state) {
  return CTRL_STATES[state] ?? `state ${state}`;
}

/** Heading in compass-style degrees 0..360 from a REP 103 yaw in degrees. */
export function wrap360(deg) {
  return ((deg % 360) + 360) % 360;
}

export function fmt(value, digits = 1) {
  return Number.isFinite(value) ? value.toFixed(digits) : "–";
}

/** Set textContent only when it changes (keeps screen readers and layout calm). */
export function setText(el, text) {
  if (el && el.textContent !== text) el.textContent = text;
}

export function setLevel(el, level) {
  if (el && el.dataset.level !== level) el.dataset.level = level;
}
