// The vehicles' safety doors: a standing WebSocket per drone, opened at page load beside the
// rosbridge connection, so Land, Hover and Emergency have a second road that no stalled web
// server can hold up (docs/safety-door.md; the protocol: server/vehicles/door_protocol.py).
//
// A DoorConnection authenticates with the console's ticket for that drone (or the pilot token),
// follows the door's heartbeats (4 Hz) and reconnects with backoff. Events (EventTarget):
// "open" after the door's hello, "ack" and "superseded" {detail: the door's message},
// "close" {detail: {code, reason}}.

export const DOOR_DEAD_MS = 1000; // no heartbeat for this long: the road is down (red)
const RETRY_MS = [500, 5000]; // reconnect backoff: first delay, longest
const REFUSED_RETRY_MS = 15000; // after the door refused our credential (close 1008)

export class DoorConnection extends EventTarget {
  /**
   * @param {string} drone the vehicle's name
   * @param {{url: string, credential: string, now?: () => number,
   *          WebSocketImpl?: typeof WebSocket}} opts
   */
  constructor(drone, { url, credential, now = () => performance.now(), WebSocketImpl = WebSocket }) {
    super();
    this.drone = drone;
    this.url = url;
    this.credential = credential;
    this.now = now;
    this.WebSocketImpl = WebSocketImpl;
    this.ws = null;
    this.authenticated = false;
    this.lastBeat = null; // this page's clock (ms) at the last hello or heartbeat
    this.flight = null; // the door's word on the drone: {state, linkOk}
    this.delayMs = RETRY_MS[0];
    this.timer = null;
    this.closed = true;
    this.lastClose = null;
  }

  start() {
    this.closed = false;
    if (!this.ws) this.open();
  }

  close() {
    this.closed = true;
    clearTimeout(this.timer);
    this.timer = null;
    if (this.ws) this.ws.close(1000, "page closed");
    this.ws = null;
    this.authenticated = false;
  }

  /** New address or credential (from the console's drone list): used from the next connect;
   *  a changed address reconnects now. */
  update(url, credential) {
    if (credential) this.credential = credential;
    if (url && url !== this.url) {
      this.url = url;
      if (this.ws) this.ws.close(1000, "door moved");
    }
  }

  /** Authenticated and a heartbeat within DOOR_DEAD_MS. */
  healthy(now = this.now()) {
    return this.authenticated && this.lastBeat !== null && now - this.lastBeat <= DOOR_DEAD_MS;
  }

  /** Send one message on the authenticated connection; false when there is none. */
  send(msg) {
    if (!this.ws || !this.authenticated || this.ws.readyState !== 1) return false;
    try {
      this.ws.send(JSON.stringify(msg));
      return true;
    } catch {
      return false;
    }
  }

  open() {
    let ws;
    try {
      ws = new this.WebSocketImpl(this.url);
    } catch {
      this.retry(RETRY_MS[1]);
      return;
    }
    this.ws = ws;
    this.authenticated = false;
    ws.onopen = () => ws.send(JSON.stringify({ op: "auth", token: this.credential || "" }));
    ws.onmessage = (ev) => this.onMessage(ev.data);
    ws.onclose = (ev) => {
      if (this.ws !== ws) return;
      this.ws = null;
      this.authenticated = false;
      this.lastClose = { code: ev.code, reason: ev.reason };
      this.dispatchEvent(new CustomEvent("close", { detail: this.lastClose }));
      this.retry(ev.code === 1008 ? REFUSED_RETRY_MS : null);
    };
  }

  retry(delayMs) {
    if (this.closed) return;
    clearTimeout(this.timer);
    const wait = delayMs ?? this.delayMs;
    this.delayMs = Math.min(this.delayMs * 2, RETRY_MS[1]);
    this.timer = setTimeout(() => {
      this.timer = null;
      if (!this.closed && !this.ws) this.open();
    }, wait);
  }

  onMessage(data) {
    let msg;
    try {
      msg = JSON.parse(data);
    } catch {
      return;
    }
    if (!msg || typeof msg !== "object") return;
    if (msg.op === "hello") {
      this.authenticated = true;
      this.lastBeat = this.now();
      this.delayMs = RETRY_MS[0];
      this.dispatchEvent(new CustomEvent("open", { detail: msg }));
    } else if (msg.op === "heartbeat") {
      this.lastBeat = this.now();
      this.flight = { state: msg.state, linkOk: msg.link_ok };
    } else if (msg.op === "ack" || msg.op === "superseded") {
      this.lastBeat = this.now();
      this.dispatchEvent(new CustomEvent(msg.op, { detail: msg }));
    } else if (msg.op === "error") {
      console.warn(`${this.drone}'s safety door refused a frame: ${msg.detail}`);
    }
  }
}

/** The doors of the fleet, by drone name, from the console's drone list. */
export class Doors extends EventTarget {
  constructor(opts = {}) {
    super();
    this.opts = opts;
    /** @type {Map<string, DoorConnection>} */
    this.byDrone = new Map();
  }

  get(drone) {
    return this.byDrone.get(drone) || null;
  }

  /**
   * A drone's door as GET /drones says it (``vehicle.door_url``, ``vehicle.door_ticket``):
   * opened on first sight, kept open after. ``fallback`` (the pilot token) authenticates when
   * the console gave no ticket (a vehicle it did not spawn); none: no door is opened.
   */
  learn(drone, vehicle, fallback) {
    const url = vehicle && vehicle.door_url;
    const credential = (vehicle && vehicle.door_ticket) || fallback;
    if (!drone || !url || !credential) return;
    const known = this.byDrone.get(drone);
    if (known) {
      known.update(url, credential);
      return;
    }
    const door = new DoorConnection(drone, { url, credential, ...this.opts });
    this.byDrone.set(drone, door);
    for (const kind of ["open", "ack", "superseded", "close"]) {
      door.addEventListener(kind, (ev) =>
        this.dispatchEvent(new CustomEvent(kind, { detail: { drone, msg: ev.detail } })),
      );
    }
    door.start();
  }
}
