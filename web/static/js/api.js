// REST client for /api/v1 (DESIGN §4) with the page's bearer token.

/** An HTTP error from the API; ``status`` is the HTTP status (0 when the server is unreachable). */
export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.name = "ApiError";
    this.status = status;
  }
}

// Any pilot may stop, lease or not (DESIGN §5): these never wait for the page's lease claim.
const STOPS = ["land", "hover", "emergency"];

export class Api {
  /**
   * @param {string} base e.g. "/api/v1"; @param {string|null} token bearer token
   * @param {(() => number)|null} clock the server's clock (Unix seconds) as the page knows it:
   *   every POST says when it was issued (X-Command-Issued), so a command that reaches the
   *   drone past its deadline is dropped, not flown late
   */
  constructor(base, token, clock = null) {
    this.base = base;
    this.token = token;
    this.clock = clock;
    /** @type {string|null} the lease holder id of this page's rosbridge session, if it holds it */
    this.leaseHolder = null;
    /** @type {Promise<unknown>|null} this page's claim of the lease while it is in flight */
    this.leaseClaim = null;
  }

  /**
   * @param {{timeoutMs?: number, headers?: object, signal?: AbortSignal|null,
   *          waitLease?: boolean}} [opts] waitLease: a POST sent while this page's claim of the
   *   lease is in flight waits for its answer (one round trip), or the server would refuse the
   *   page's own command as another pilot's; stops pass false (any pilot may stop, at once)
   */
  async request(
    method,
    path,
    body,
    { timeoutMs = 8000, headers: extra = {}, signal = null, waitLease = true } = {},
  ) {
    const headers = { Accept: "application/json", ...extra };
    if (this.token) headers.Authorization = `Bearer ${this.token}`;
    if (body !== undefined) headers["Content-Type"] = "application/json";
    // Stamped before any wait: when the operator gave it.
    if (method === "POST" && this.clock) headers["X-Command-Issued"] = this.clock().toFixed(3);
    if (method === "POST" && waitLease && this.leaseClaim) await this.leaseClaim;
    // The pilot lease this page holds on its rosbridge session: REST commands speak for it.
    if (this.leaseHolder) headers["X-Pilot-Lease"] = this.leaseHolder;
    const ctrl = new AbortController();
    const timer = setTimeout(() => ctrl.abort(), timeoutMs);
    if (signal?.aborted) ctrl.abort();
    signal?.addEventListener("abort", () => ctrl.abort(), { once: true }); // the caller gave up
    let resp;
    try {
      resp = await fetch(this.base + path, {
        method,
        headers,
        body: body === undefined ? undefined : JSON.stringify(body),
        signal: ctrl.signal,
        cache: "no-store",
      });
    } catch (err) {
      throw new ApiError(0, ctrl.signal.aborted ? "request timed out" : "server unreachable");
    } finally {
      clearTimeout(timer);
    }
    const text = await resp.text();
    let data = null;
    if (text) {
      try {
        data = JSON.parse(text);
      } catch {
        data = { detail: text };
      }
    }
    if (!resp.ok) {
      const detail = data && (data.detail ?? data.message ?? data.error);
      const msg = typeof detail === "string" ? detail : JSON.stringify(detail ?? resp.statusText);
      throw new ApiError(resp.status, msg);
    }
    return data;
  }

  get(path, opts) {
    return this.request("GET", path, undefined, opts);
  }

  post(path, body = {}, opts) {
    return this.request("POST", path, body, opts);
  }

  world() {
    return this.get("/world");
  }

  drones() {
    return this.get("/drones");
  }

  drone(id) {
    return this.get(`/drones/${encodeURIComponent(id)}`);
  }

  /**
   * POST /drones/{id}/{takeoff|land|hover|emergency|reset}; ``source`` (button, keyboard, map)
   * goes to the server's audit log with the action.
   */
  action(id, action, source = "button") {
    return this.post(`/drones/${encodeURIComponent(id)}/${action}`, {}, {
      timeoutMs: 4000,
      headers: { "X-Command-Source": source },
      waitLease: !STOPS.includes(action),
    });
  }

  /**
   * A stop down the server road: POST /drones/{id}/{land|hover|emergency} with the stop's
   * ``{id, issued}`` (the same id as on the safety door, so the vehicle runs it once).
   */
  stop(id, action, body, signal, source = "button") {
    return this.post(`/drones/${encodeURIComponent(id)}/${action}`, body, {
      timeoutMs: 3000,
      headers: { "X-Command-Source": source },
      signal,
      waitLease: false,
    });
  }

  command(text, { confidence, drone } = {}) {
    const body = { text };
    if (confidence !== undefined) body.confidence = confidence;
    if (drone) body.drone = drone;
    return this.post("/command", body);
  }
}
