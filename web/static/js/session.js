// Session: connection state, role (pilot/observer), the pilot lease, and the drone selector.

export const TOPIC_TYPES = Object.freeze({
  "/ardrone/navdata": "ardrone_autonomy/Navdata",
  "/ardrone/image_raw/compressed": "sensor_msgs/CompressedImage",
  "/ardrone/takeoff": "std_msgs/Empty",
  "/ardrone/land": "std_msgs/Empty",
  "/ardrone/reset": "std_msgs/Empty",
  "/cmd_vel": "geometry_msgs/Twist",
  "/uav/pose": "geometry_msgs/PoseStamped",
  "/uav/markers": "uav_console/MarkerArray",
  "/uav/task": "uav_console/TaskStatus",
  "/console/utterance": "uav_console/Utterance",
  "/console/reply": "uav_console/Reply",
  "/console/state": "uav_console/DialogState",
  "/fleet/status": "uav_console/FleetStatus",
});

/** The page's token: ?token=… in the URL (kept for this tab so a reload without it works). */
export function pageToken(loc = window.location, store = window.sessionStorage) {
  const fromUrl = new URLSearchParams(loc.search).get("token");
  try {
    if (fromUrl) store.setItem("uavc.token", fromUrl);
    return fromUrl || store.getItem("uavc.token");
  } catch {
    return fromUrl;
  }
}

/** Drone names from GET /api/v1/drones (each entry's ``name`` or ``id``). */
export function droneNames(list) {
  if (!Array.isArray(list)) return [];
  return list.map((d) => d?.name ?? d?.id ?? d?.drone).filter((n) => typeof n === "string");
}

/** The role in the server's answer to our ``auth`` op ("authenticated as pilot"), or null. */
export function roleFromStatus(msg) {
  const m = /authenticated as (\w+)/i.exec(msg || "");
  return m ? m[1].toLowerCase() : null;
}

/** The pilot-lease service of the rosbridge endpoint: {action: status|acquire|release, take_over}. */
export const LEASE_SERVICE = "/console/lease";

/** Does a status message from the server say our role was refused, and which role? */
export function refusedRole(msg) {
  const m = /\b(observer|pilot)\b[^.]*\bmay not\b/i.exec(msg || "");
  return m ? m[1].toLowerCase() : null;
}

/** Does a status message say the pilot lease moved (taken over, or held by someone else)? */
export function leaseNews(msg) {
  const text = msg || "";
  if (!/lease|took over|taken over|take over|takeover/i.test(text)) return null;
  if (/you (now )?hold|granted|acquired|you are the pilot|you took over/i.test(text)) return "mine";
  return "lost";
}
