// A small rosbridge v2 client (JSON over WebSocket) with automatic reconnect and resubscribe.
//
// Why our own: the console needs only publish/subscribe/call_service/status, and it must
// re-advertise and resubscribe by itself after the server restarts. Ops and ids follow
// RobotWebTools/rosbridge_suite ROSBRIDGE_PROTOCOL.md and the id shapes roslibjs uses
// (`subscribe:/t:N`, `advertise:/t:N`, `publish:/t:N`, `call_service:<name>:<n>`).
//
// Events (EventTarget): "state" {detail: {state, attempt}} with state one of
// "connecting" | "open" | "closed"; "status" {detail: status op from the server (level, msg, id)};
// "open" after each (re)connection once subscriptions are restored.

export const STATES = Object.freeze({ CONNECTING: "connecting", OPEN: "open", CLOSED: "closed" });

/** Error raised for a failed or timed-out service call. */
export class ServiceCallError extends Error {
  constructor(service, message) {
    super(`${service}: ${message}`);
    this.name = "ServiceCallError";
    this.service = service;
  }
}

export class RosbridgeClient extends EventTarget {
  /**
   * @param {string} url ws:// or wss:// address of the rosbridge endpoint (token in the query).
   * @param {{minDelayMs?: number, maxDelayMs?: number, WebSocketImpl?: typeof WebSocket}} [opts]
   */
  constructor(url, opts = {}) {
    super();
    this.url = url;
    this.minDelayMs = opts.minDelayMs ?? 250;
    this.maxDelayMs = opts.maxDelayMs ?? 3000;
    this.WebSocketImpl = opts.WebSocketImpl ?? WebSocket;
    this.state = STATES.CLOSED;
    this.ws = null;
    this.attempt = 0;
    this.counter = 0;
    this.closedByUser = false;
    this.reconnectTimer = null;
    /** topic -> {type, callbacks:Set, options, id} */
    this.subscriptions = new Map();
    /** topic -> {type, id} */
    this.advertised = new Map();
    /** id -> {resolve, reject, timer, service} */
    this.pendingCalls = new Map();
  }

  nextId(prefix) {
    this.counter += 1;
    return `${prefix}:${this.counter}`;
  }

  /** Open the connection (and keep it open: reconnects with backoff until close()). */
  connect() {
    this.closedByUser = false;
    this.openSocket();
  }

  /** Close for good; no reconnect. */
  close() {
    this.closedByUser = true;
    clearTimeout(this.reconnectTimer);
    if (this.ws) this.ws.close(1000, "client closing");
    this.setState(STATES.CLOSED);
  }

  setState(state) {
    if (this.state === state) return;
    this.state = state;
    this.dispatchEvent(new CustomEvent("state", { detail: { state, attempt: this.attempt } }));
  }

  openSocket() {
    this.setState(STATES.CONNECTING);
    let ws;
    try {
      ws = new this.WebSocketImpl(this.url);
    } catch (err) {
      this.scheduleReconnect();
      return;
    }
    this.ws = ws;
    ws.onopen = () => {
      if (this.ws !== ws) return;
      this.attempt = 0;
      this.restore();
      this.setState(STATES.OPEN);
      this.dispatchEvent(new Event("open"));
    };
    ws.onmessage = (ev) => {
      if (this.ws === ws) this.handleText(ev.data);
    };
    ws.onclose = () => {
      if (this.ws !== ws) return;
      this.ws = null;
      this.failPendingCalls("connection closed");
      if (this.closedByUser) {
        this.setState(STATES.CLOSED);
      } else {
        this.scheduleReconnect();
      }
    };
    // onerror is always followed by onclose; nothing to do here (and no console noise).
    ws.onerror = () => {};
  }

  scheduleReconnect() {
    this.setState(STATES.CLOSED);
    if (this.closedByUser) return;
    this.attempt += 1;
    // Exponential backoff with a cap; a little jitter so many consoles do not reconnect in step.
    const base = Math.min(this.maxDelayMs, this.minDelayMs * 2 ** Math.min(this.attempt - 1, 6));
    const delay = base * (0.8 + 0.4 * Math.random());
    clearTimeout(this.reconnectTimer);
    this.reconnectTimer = setTimeout(() => this.openSocket(), delay);
  }

  /** Re-send every advertise and subscribe after a (re)connection. */
  restore() {
    for (const [topic, adv] of this.advertised) {
      this.send({ op: "advertise", id: adv.id, topic, type: adv.type });
    }
    for (const [topic, sub] of this.subscriptions) {
      this.send({ op: "subscribe", id: sub.id, topic, type: sub.type, ...sub.options });
    }
  }

  failPendingCalls(reason) {
    for (const [id, call] of this.pendingCalls) {
      clearTimeout(call.timer);
      call.reject(new ServiceCallError(call.service, reason));
      this.pendingCalls.delete(id);
    }
  }

  /** Send one op if the socket is open; returns whether it was sent. */
  send(op) {
    if (!this.ws || this.ws.readyState !== 1) return false;
    this.ws.send(JSON.stringify(op));
    return true;
  }

  handleText(text) {
    if (typeof text !== "string") return; // we never ask for binary (CBOR/PNG) encodings
    let op;
    try {
      op = JSON.parse(text);
    } catch {
      this.dispatchEvent(new CustomEvent("status", { detail: { level: "error", msg: "bad frame from server" } }));
      return;
    }
    switch (op.op) {
      case "publish": {
        const sub = this.subscriptions.get(op.topic);
        if (!sub) return;
        for (const cb of [...sub.callbacks]) {
          try {
            cb(op.msg);
          } catch (err) {
            // A broken panel must not stop the others; report once per error in the page log.
            this.dispatchEvent(new CustomEvent("callback-error", { detail: { topic: op.topic, error: err } }));
          }
        }
        return;
      }
      case "service_response": {
        const call = this.pendingCalls.get(op.id);
        if (!call) return;
        this.pendingCalls.delete(op.id);
        clearTimeout(call.timer);
        if (op.result === false) {
          const why = typeof op.values === "string" ? op.values : JSON.stringify(op.values ?? "failed");
          call.reject(new ServiceCallError(call.service, why));
        } else {
          call.resolve(op.values ?? {});
        }
        return;
      }
      case "status":
        this.dispatchEvent(new CustomEvent("status", { detail: op }));
        return;
      default:
        return;
    }
  }

  /**
   * Subscribe to a topic; several callbacks on one topic share one server subscription.
   * @returns {{unsubscribe: () => void}}
   */
  subscribe(topic, type, callback, options = {}) {
    let sub = this.subscriptions.get(topic);
    if (!sub) {
      const clean = {};
      for (const key of ["throttle_rate", "queue_length"]) {
        if (options[key] !== undefined) clean[key] = options[key];
      }
      sub = { type, callbacks: new Set(), options: clean, id: this.nextId(`subscribe:${topic}`) };
      this.subscriptions.set(topic, sub);
      this.send({ op: "subscribe", id: sub.id, topic, type, ...clean });
    }
    sub.callbacks.add(callback);
    return {
      unsubscribe: () => {
        sub.callbacks.delete(callback);
        if (sub.callbacks.size === 0 && this.subscriptions.get(topic) === sub) {
          this.subscriptions.delete(topic);
          this.send({ op: "unsubscribe", id: sub.id, topic });
        }
      },
    };
  }

  /** Declare that we publish ``type`` on ``topic`` (kept across reconnects). */
  advertise(topic, type) {
    if (this.advertised.has(topic)) return;
    const adv = { type, id: this.nextId(`advertise:${topic}`) };
    this.advertised.set(topic, adv);
    this.send({ op: "advertise", id: adv.id, topic, type });
  }

  /**
   * Publish ``msg`` on ``topic`` (advertising it first); returns the op id, or null when the
   * connection is down (the caller tells the operator: a control command must never vanish
   * silently). ``issued``: when the operator gave a command (server-clock Unix seconds), sent
   * beside ``msg`` so the server can drop it if it arrives past its deadline.
   */
  publish(topic, type, msg, { issued } = {}) {
    this.advertise(topic, type);
    const id = this.nextId(`publish:${topic}`);
    const op = { op: "publish", id, topic, msg };
    if (Number.isFinite(issued)) op.issued = issued;
    return this.send(op) ? id : null;
  }

  /** Call a service; resolves with its ``values``, rejects with ServiceCallError. */
  callService(service, args = {}, { timeoutMs = 5000 } = {}) {
    return new Promise((resolve, reject) => {
      const id = this.nextId(`call_service:${service}`);
      if (!this.send({ op: "call_service", id, service, args })) {
        reject(new ServiceCallError(service, "not connected"));
        return;
      }
      const timer = setTimeout(() => {
        this.pendingCalls.delete(id);
        reject(new ServiceCallError(service, `no answer within ${timeoutMs} ms`));
      }, timeoutMs);
      this.pendingCalls.set(id, { resolve, reject, timer, service });
    });
  }
}

/** The rosbridge URL for this page: same host, /rosbridge, with the page's token. */
export function rosbridgeUrl(location, token) {
  const scheme = location.protocol === "https:" ? "wss:" : "ws:";
  const query = token ? `?token=${encodeURIComponent(token)}` : "";
  return `${scheme}//${location.host}/rosbridge${query}`;
}
