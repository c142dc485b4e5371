// The operator console: wires the rosbridge client and the REST API to the panels.
//
// Talks to the backend only through /rosbridge (rosbridge v2 JSON) and /api/v1 (bearer token),
// DESIGN §4. Direct control never waits for the dialog.

import { AlertBanner, checkVoices } from "./alerts.js";
import { Api, ApiError } from "./api.js";
import { CameraPanel } from "./camera.js";
import { CameraFeed } from "./camera_feed.js";
import { Controls } from "./controls.js";
import { DialogPanel } from "./dialog.js";
import { DOOR_DEAD_MS, Doors } from "./door.js";
import { Freshness, TICK_MS as FRESHNESS_TICK_MS } from "./freshness.js";
import { MapPanel } from "./map.js";
import { RosbridgeClient, STATES, rosbridgeUrl } from "./rosbridge.js";
import {
  LEASE_SERVICE,
  TOPIC_TYPES,
  droneNames,
  leaseNews,
  pageToken,
  refusedRole,
  roleFromStatus,
} from "./session.js";
import { RecordingsMenu } from "./recordings.js";
import { ReplayBar, pageReplay, replayApiBase, replayRosbridgeUrl } from "./replay.js";
import { StatusBar, flightLabel, lostWhileAway } from "./status.js";
import { STOP_ACTIONS, StopSender, stopText } from "./stops.js";
import { VoiceInput } from "./voice.js";
import { TelemetryPanel } from "./telemetry.js";
import { TrainingPanel } from "./training.js";
import { droneTopic, quaternionYaw, stampSeconds } from "./util.js";

const $ = (id) => document.getElementById(id);
// Flight labels (status.js flightLabel) in which a take-off has nothing to do.
const AIRBORNE = ["Flying", "Hovering", "Taking off"];
const STATUS_POLL_MS = 1000;
const ROADS_CHECK_MS = 250;
// The console's own heartbeat on rosbridge (server/vehicles/central.py, 10 Hz): the page calls
// the server road down when none came for DOOR_DEAD_MS, though its socket may look open.
const SERVER_HEARTBEAT = "/vehicles/heartbeat";

class Console {
  constructor() {
    this.token = pageToken();
    this.clockOffset = 0; // server time - local time, seconds
    // Commands say when they were issued, on the server's clock (deadlines: docs/deadlines.md).
    this.serverNow = () => Date.now() / 1000 + this.clockOffset;
    // ?replay=FLIGHT: a recorded flight, read-only, on a graph of its own (replay.js).
    this.replayId = pageReplay();
    const base = this.replayId ? replayApiBase(this.replayId) : "/api/v1";
    this.api = new Api(base, this.token, this.serverNow);
    this.liveApi = this.replayId ? new Api("/api/v1", this.token) : this.api;
    this.ros = new RosbridgeClient(
      this.replayId
        ? replayRosbridgeUrl(window.location, this.replayId)
        : rosbridgeUrl(window.location, this.token),
    );
    this.serverSpeaking = 0; // replies the server's voice is playing now (serverSpeak)
    this.drones = [];
    this.fleet = false;
    this.drone = null;
    this.role = null;
    this.haveLease = null;
    this.droneSubs = [];
    this.everOpened = false;
    this.serverBeatAt = null; // performance.now() of the server's last heartbeat
    this.serverStalled = false;
    this.vehiclePid = null; // {drone, pid} of the selected drone's vehicle process, once known
    // Stops go down two roads (docs/safety-door.md): REST and each drone's safety door.
    this.doors = new Doors();
    this.stops = new StopSender({
      rest: (stop, body, signal) => this.api.stop(stop.drone, stop.action, body, signal, stop.source),
      door: (drone) => this.doors.get(drone),
      serverNow: () => Date.now() / 1000 + this.clockOffset,
      fleet: () => this.fleet,
    });
    this.doors.addEventListener("ack", (ev) => this.stops.doorAck(ev.detail.msg));
    this.doors.addEventListener("superseded", (ev) => this.stops.doorSuperseded(ev.detail.msg));
    this.doors.addEventListener("open", (ev) => this.stops.doorOpened(ev.detail.drone));
    this.stops.addEventListener("change", (ev) => this.onStopChange(ev.detail));

    this.camera = new CameraPanel(
      { img: $("camera"), empty: $("camera-empty"), fps: $("cam-fps"), latency: $("cam-latency") },
      () => Date.now() / 1000 + this.clockOffset,
    );
    this.camera.onFrame = () => this.freshness.beat("camera");
    this.cameraFeed = new CameraFeed(this.ros, this.camera, () => Date.now() / 1000 + this.clockOffset);
    this.telemetry = new TelemetryPanel(document);
    // Navdata streams (~15 Hz): from its first message the vehicle is judged as a stream.
    this.telemetry.onNavdataSeen = () => {
      this.freshness.setPeriod("vehicle", 0);
      this.freshness.beat("vehicle");
    };
    this.status = new StatusBar(document);
    this.telemetry.onFlight = (label, battery) => {
      this.status.setFlight(label);
      if (battery !== null && battery !== undefined) this.status.setBattery(battery);
      this.map.setFlightLabel(this.drone, label);
    };
    this.telemetry.onLink = (text, level) => this.status.setLink(text, level);
    this.alertBanner = new AlertBanner(
      { banner: $("alert-banner"), text: $("alert-text"), ack: $("alert-ack") },
      { onAck: (text) => this.dialog.addSystem(`Acknowledged: ${text}`) },
    );
    // Age on every value: one rule for every panel (freshness.js).
    this.freshness = new Freshness({ alarms: this.alertBanner });
    this.defineSources();
    this.beforeDrop = null; // what the status bar showed when the connection dropped
    this.map = new MapPanel(
      $("map"),
      {
        popover: $("map-popover"),
        text: $("map-popover-text"),
        go: $("map-go"),
        cancel: $("map-cancel"),
        caption: $("map-caption"),
        focus: $("map-focus"),
      },
      (id) => this.goToMarker(id),
    );
    this.dialog = new DialogPanel({
      log: $("dialog"),
      alerts: $("alerts"),
      mute: $("mute"),
      state: $("dialog-state"),
      voiceNote: $("voice-note"),
      lastReply: $("last-reply"),
    }, {
      serverSpeak: (text) => this.serverSpeak(text),
      now: () => this.pageNow(),
      replay: () => Boolean(this.replayId),
      // "Did you say …?" answered by a button: to the drone that asked (dialog.js addAnswers).
      onAnswer: (answer, drone) => this.sendUtterance(answer, "button", 1, drone || this.drone),
    });
    // Speech: server (offline) or browser recogniser, push-to-talk, hands-free.
    this.speech = new VoiceInput(
      {
        button: $("mic"),
        interim: $("interim"),
        engine: $("recognizer"),
        handsfree: $("handsfree"),
        label: $("recognizer-label"),
      },
      {
        token: this.token,
        lease: () => this.api.leaseHolder,
        onFinal: (text, confidence) => this.sendUtterance(text, "speech", confidence),
        onNotice: (notice) => this.notice(notice),
        // Hands-free does not listen to the console's own spoken replies (voice.js outgoing).
        speaking: () => this.serverSpeaking > 0 || Boolean(window.speechSynthesis?.speaking),
        hush: () => this.hush(),
      },
    );
    this.controls = new Controls(document.body, {
      action: (name, source) => this.act(name, source),
      close: () => this.closeOpen(),
      disarmedKey: (key) =>
        this.flash(
          `“${key.toUpperCase()}” moves the drone only with “Keyboard flying” on (Direct control).`,
          "info",
        ),
      twist: (t) => this.publishTwist(t),
      focusInput: () => $("text-input").focus(),
      mic: () => this.speech.toggle(),
      describe: () => this.describe(),
    });
    $("describe").addEventListener("click", () => this.describe());
    // Simulator faults for operator training: a pilot with the lease, a simulated drone, live.
    this.training = new TrainingPanel($("training"), this.api, {
      drone: () => this.drone,
      role: () => this.role,
      lease: () => this.haveLease,
      replay: () => document.body.dataset.replay === "1",
      say: (text) => this.dialog.addSystem(text),
    });

    $("input-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      const input = $("text-input");
      const text = input.value.trim();
      if (!text) return;
      if (this.sendUtterance(text, "text", 1.0)) input.value = "";
    });
    $("drone-select").addEventListener("change", (ev) => this.selectDrone(ev.target.value));
    $("takeover").addEventListener("click", () => this.takeOver());

    this.ros.addEventListener("state", (ev) => this.onConnState(ev.detail.state));
    this.ros.addEventListener("open", () => this.onOpen());
    this.ros.addEventListener("status", (ev) => this.onStatus(ev.detail));
    this.ros.addEventListener("callback-error", (ev) => console.warn("panel error", ev.detail));

    this.subscribeGlobal();
    this.registerPanels();
    this.layoutDock();
    window.addEventListener("resize", () => this.layoutDock());
    if (window.ResizeObserver) {
      const ro = new ResizeObserver(() => this.layoutDock());
      for (const id of ["dock", "messages", "replay-bar"]) ro.observe($(id));
      ro.observe(document.querySelector(".topbar"));
    }
  }

  async start() {
    if (!this.token) {
      // Nothing works without one (REST says 401, rosbridge closes): say so and stop here.
      this.banner(
        "No token in the address. Open the link printed by `uav-console serve` (…/?token=…).",
        "alert",
        "rest",
      );
      this.onConnState(STATES.CLOSED);
      return;
    }
    await this.loadServerInfo();
    // A replay: a timeline bar; a seek clears the trails and the dialog shown so far.
    this.replay = new ReplayBar(this.api, $("replay-bar"), () => {
      this.map.clearTrails();
      this.dialog.clear();
    });
    this.replay.start().then((on) => {
      if (on && this.replayId) document.title = `uav-console — replay of ${this.replayId}`;
    });
    this.recordings = new RecordingsMenu(
      this.liveApi,
      { pill: $("rec"), menu: $("recordings"), list: $("recordings-list") },
    );
    this.recordings.start();
    this.ros.connect();
    this.checkVoice();
    setInterval(() => this.pollDrone(), STATUS_POLL_MS);
    setInterval(() => this.checkRoads(), ROADS_CHECK_MS);
    setInterval(() => this.checkFreshness(), FRESHNESS_TICK_MS);
  }

  // ---- age on every value ---------------------------------------------------------------------
  /** The sources whose silence the page watches: the server, the selected drone's vehicle and
   *  camera (redefined when another drone is selected), the fleet status (fleets only). */
  defineSources(drone = this.drone) {
    const f = this.freshness;
    if (!f.sources.has("server")) {
      f.source("server", {
        alarm: (age) => `No word from the server for ${age}: everything shown is ${age} old.`,
        back: (age) => `The server answers again (it was silent for ${age}).`,
      });
    }
    if (!drone) return;
    const name = drone;
    f.source("vehicle", {
      upstream: "server",
      periodS: STATUS_POLL_MS / 1000, // the REST snapshot; a stream once navdata flows
      key: `fresh:vehicle:${name}`,
      alarm: (age, why) => `${name}: no telemetry for ${age}${why ? ` (${why})` : ""}.`,
      back: (age, why) => `${name}: telemetry is back (it was silent for ${age}${why ? `; ${why}` : ""}).`,
    });
    f.source("camera", {
      upstream: "vehicle",
      key: `fresh:camera:${name}`,
      alarm: (age) => `${name}: no picture from the camera for ${age}.`,
      back: (age) => `${name}: the camera is back (it was silent for ${age}).`,
    });
  }

  /** Which panel shows what: each greys out and says its age when a source it needs stops. */
  registerPanels() {
    const f = this.freshness;
    const drone = ["server", "vehicle"];
    f.panel($("telemetry-panel"), drone);
    f.panel($("map-panel"), [...drone, "fleet"]);
    f.panel($("camera-panel"), ["server", "vehicle", "camera"], {
      show: (age) => this.camera.showAge(age),
    });
    f.panel($("statusbar"), ["server"], { show: (age) => this.status.showAge(age) });
    for (const id of ["sb-flight", "sb-battery", "sb-task"]) f.panel($(id), drone, { badge: null });
    f.panel($("fleet-list"), ["server", "fleet"], { badge: null });
    f.panel($("rec"), ["server"], { badge: null });
  }

  checkFreshness() {
    // `uav-console replay` plays recorded time: a paused replay is not a silent source.
    this.freshness.suspend(!$("replay-bar").hidden);
    this.freshness.tick();
    document.body.dataset.stale = [...this.freshness.sources.keys()]
      .filter((n) => this.freshness.staleAge(n) !== null)
      .join(" ");
  }

  /** World and drones: fetched at start and again after every reconnection. */
  async loadServerInfo() {
    try {
      const [world, drones] = await Promise.all([this.api.world(), this.api.drones()]);
      this.map.setWorld(world);
      this.setDrones(droneNames(drones));
      // A standing connection to every drone's safety door, from the first load on.
      for (const d of Array.isArray(drones) ? drones : []) this.learnDoor(d.name, d.vehicle);
      if ($("banner").dataset.source === "rest") this.banner(null);
      this.pollDrone();
    } catch (err) {
      if (err instanceof ApiError && err.status === 401) {
        const why = this.token
          ? "The server refused this page's token."
          : "No token in the address.";
        this.banner(`${why} Open the link printed by \`uav-console serve\` (…/?token=…).`, "alert", "rest");
      } else if (err instanceof ApiError && err.status === 0) {
        // Server down: the rosbridge reconnect loop will bring us back.
      } else {
        this.banner(`Could not load the server's state: ${err.message}`, "warn", "rest");
      }
    }
  }

  // ---- session ---------------------------------------------------------------------------
  onConnState(state) {
    const el = $("conn");
    el.dataset.state = state;
    if (state === STATES.OPEN && this.serverStalled) {
      // The socket is open but the server sends nothing: never "Connected" then.
      el.textContent = "Server not answering";
      el.className = "pill pill-alert";
      el.dataset.state = "stalled";
    } else if (state === STATES.OPEN) {
      el.textContent = "Connected";
      el.className = "pill pill-ok";
    } else if (state === STATES.CONNECTING) {
      el.textContent = this.everOpened ? "Reconnecting…" : "Connecting…";
      el.className = "pill pill-warn";
    } else {
      el.textContent = this.everOpened ? "Connection lost — retrying" : "Not connected";
      el.className = "pill pill-alert";
      this.controls.releaseAll(false);
    }
    if (state !== STATES.OPEN && this.everOpened && !this.status.staleSince) {
      this.beforeDrop = this.status.snapshot();
      this.status.markStale();
    }
    this.renderEnabled();
  }

  async onOpen() {
    const again = this.everOpened;
    this.everOpened = true;
    this.serverBeatAt = performance.now(); // its first heartbeat is on the way
    // The connection is already authenticated by ?token=; the auth op makes the server say as
    // whom ("authenticated as pilot"), which is how the page learns its role.
    // Status messages default to errors only (ROSBRIDGE_PROTOCOL.md §3.2); lease warnings and the
    // auth answer are "warning" and "info".
    this.ros.send({ op: "set_level", id: "level:info", level: "info" });
    this.ros.send({ op: "auth", id: "auth:role", token: this.token || "" });
    this.syncClock();
    if (again) {
      this.dialog.addSystem("Reconnected.");
      this.camera.reset();
    }
    // After a restart the world or the fleet may differ; at first load the REST calls may have
    // raced a server that was still starting.
    if (again || !this.drone || !this.map.world) await this.loadServerInfo();
    await this.pollDrone(true);
    if (this.status.staleSince) this.reportLoss();
  }

  /** Estimate server clock offset with rosapi get_time (half the round trip, NTP-style). */
  async syncClock() {
    // On this very machine both sides read one clock: an estimate could only add error.
    const host = window.location.hostname;
    if (/^127\./.test(host) || host === "localhost" || host === "[::1]") {
      this.clockOffset = 0;
      return;
    }
    try {
      const t0 = Date.now() / 1000;
      const values = await this.ros.callService("/rosapi/get_time", {}, { timeoutMs: 2000 });
      const t1 = Date.now() / 1000;
      const server = stampSeconds(values.time);
      if (server !== null) this.clockOffset = server - (t0 + t1) / 2;
    } catch {
      this.clockOffset = 0; // same machine is the common case; latency stays meaningful
    }
  }

  setRole(role) {
    this.role = role;
    const el = $("role");
    el.textContent = role === "pilot" ? "pilot" : role === "observer" ? "observer (watch only)" : `role: ${role}`;
    el.className = `pill ${role === "observer" ? "pill-warn" : "pill-ok"}`;
    el.dataset.role = role;
    this.renderEnabled();
  }

  setLease(mine) {
    this.haveLease = mine;
    this.renderEnabled();
  }

  /** Observer, or a pilot without the lease: controls off; any pilot keeps Land, Hover and
   *  EMERGENCY STOP (the server lets any pilot stop, lease or not: DESIGN §5). */
  renderEnabled() {
    const connected = this.ros.state === STATES.OPEN;
    const observer = this.role === "observer";
    const lostLease = this.role === "pilot" && this.haveLease === false;
    const can = !observer && !lostLease;
    for (const el of document.querySelectorAll("[data-control], #text-input, #mic")) {
      el.disabled = !can;
    }
    // The stops are never disabled for a pilot: even without the lease a pilot may stop the
    // drone; observers cannot command at all.
    for (const id of ["btn-emergency", "btn-land", "btn-hover"]) $(id).disabled = observer;
    this.controls.setEnabled(can, !observer);
    const why = observer ? "observers watch only" : lostLease ? "another pilot holds the controls" : "";
    this.speech?.setAllowed(can, why); // hands-free too: the server refuses an observer's speech
    $("takeover").hidden = !lostLease;
    document.body.dataset.role = this.role || "";
    document.body.dataset.connected = String(connected);
    if (observer) $("text-input").placeholder = "Observers watch only";
    this.training?.refresh();
  }

  /** A pilot takes the lease when it is free; when another pilot holds it, offers take-over.
   *  While the claim is in flight the page's REST commands wait for it (api.js leaseClaim). */
  claimLease() {
    return this.whileClaiming(this.claimLeaseNow());
  }

  /** Run ``claim`` (never rejects) as the page's lease claim in flight. */
  async whileClaiming(claim) {
    this.api.leaseClaim = claim;
    try {
      await claim;
    } finally {
      if (this.api.leaseClaim === claim) this.api.leaseClaim = null;
    }
  }

  async claimLeaseNow() {
    try {
      let lease = await this.ros.callService(LEASE_SERVICE, { action: "status" });
      if (!lease.held_by_me && !lease.holder) {
        lease = await this.ros.callService(LEASE_SERVICE, { action: "acquire" });
      }
      this.setLease(!!lease.held_by_me);
      this.api.leaseHolder = lease.held_by_me ? lease.holder : null;
      if (!lease.held_by_me) {
        this.banner(
          "Another pilot holds the controls. Press “Take over as pilot” to command.",
          "warn",
          "lease",
        );
      } else if ($("banner").dataset.source === "lease") {
        this.banner(null);
      }
    } catch (err) {
      // No lease service (an older server): commands go through and the server decides.
      this.setLease(null);
    }
  }

  takeOver() {
    return this.whileClaiming(this.takeOverNow());
  }

  async takeOverNow() {
    try {
      const lease = await this.ros.callService(LEASE_SERVICE, { action: "acquire", take_over: true });
      this.setLease(!!lease.held_by_me);
      this.api.leaseHolder = lease.held_by_me ? lease.holder : null;
      if (lease.held_by_me) {
        this.dialog.addSystem("You took over as pilot; the other pilot was told.");
        if ($("banner").dataset.source === "lease") this.banner(null);
      }
    } catch (err) {
      this.flash(`Could not take over: ${err.message}`, "alert");
    }
  }

  onStatus(st) {
    const msg = st.msg || "";
    const role = roleFromStatus(msg);
    if (role) {
      this.setRole(role);
      if (role === "pilot") this.claimLease();
      return;
    }
    const refused = refusedRole(msg);
    if (refused === "observer" && this.role !== "observer") this.setRole("observer");
    const lease = leaseNews(msg);
    if (lease === "lost") {
      // The server says it twice (a warning naming the new holder, then an error): tell once.
      if (this.haveLease !== false) {
        this.dialog.addSystem(msg);
        this.banner("Another pilot took over the controls. Press “Take over as pilot” to command again.", "warn", "lease");
      }
      this.setLease(false);
      return;
    }
    if (lease === "mine") {
      this.setLease(true);
      if ($("banner").dataset.source === "lease") this.banner(null);
      return;
    }
    if (st.level === "error" || st.level === "warning" || st.level === "warn") {
      this.dialog.addSystem(`Server: ${msg}`);
      this.flash(`Server refused: ${msg}`, "warn");
    }
  }

  /** After a reconnection: fresh values, and what changed while the page was away. */
  reportLoss() {
    const since = this.status.staleSince;
    this.status.markFresh();
    const lost = lostWhileAway(this.beforeDrop, this.status.snapshot());
    this.beforeDrop = null;
    const t = since ? since.toLocaleTimeString([], { hour12: false }) : "?";
    const text = lost.length
      ? `While disconnected (since ${t}): ${lost.join(" ")}`
      : `While disconnected (since ${t}): nothing changed.`;
    this.dialog.addSystem(text);
    if (lost.length) this.banner(text, "warn", "reconnect");
  }

  setDrones(names) {
    const list = names.length ? names : ["uav1"];
    this.drones = list;
    this.fleet = list.length > 1;
    this.dialog.setFleet(this.fleet);
    const sel = $("drone-select");
    sel.replaceChildren(...list.map((n) => new Option(n, n)));
    $("drone-select-wrap").hidden = !this.fleet;
    if (this.fleet && !this.freshness.sources.has("fleet")) {
      // The central's fleet status, once a second (server/fleet/node.py publish_period_s).
      this.freshness.source("fleet", {
        upstream: "server",
        periodS: 1,
        alarm: (age) => `No fleet status for ${age}: the other drones are shown as they were.`,
        back: (age) => `The fleet status is back (it was silent for ${age}).`,
      });
    }
    $("fleet-list").hidden = !this.fleet;
    const stored = window.localStorage.getItem("uavc.drone");
    const want = list.includes(this.drone) ? this.drone : list.includes(stored) ? stored : list[0];
    sel.value = want;
    if (want !== this.drone) this.selectDrone(want);
  }

  selectDrone(name) {
    this.drone = name;
    try {
      window.localStorage.setItem("uavc.drone", name);
    } catch {
      /* private mode */
    }
    this.controls.releaseAll(true);
    this.training?.refresh();
    for (const s of this.droneSubs) s.unsubscribe();
    this.camera.reset();
    this.defineSources(name);
    this.map.setSelected(name);
    this.status.setDrone(name);
    const t = (n) => droneTopic(n, name, this.fleet);
    const sub = (topic, cb, opts) => this.ros.subscribe(t(topic), TOPIC_TYPES[topic], cb, opts);
    this.droneSubs = [
      sub("/ardrone/navdata", (m) => this.telemetry.onNavdata(m), { throttle_rate: 50, queue_length: 1 }),
      // throttled to what this page can show, so frames never queue (camera_feed.js)
      this.cameraFeed.attach(t("/ardrone/image_raw/compressed"), TOPIC_TYPES["/ardrone/image_raw/compressed"]),
      sub("/uav/pose", (m) => {
        this.map.onPose(name, m);
        this.telemetry.onPoseYaw(quaternionYaw(m?.pose?.orientation));
      }, { throttle_rate: 50, queue_length: 1 }),
      sub("/uav/markers", (m) => this.map.onMarkers(m), { throttle_rate: 200, queue_length: 1 }),
      sub("/uav/task", (m) => {
        this.telemetry.onTask(m);
        this.map.onTask(m);
      }),
    ];
    document.body.dataset.drone = name;
  }

  /** Unix seconds of "now" as the page shows times: the recording's in a replay. */
  pageNow() {
    const recorded = this.replay?.active ? this.replay.now() : null;
    return recorded ?? Date.now() / 1000 + this.clockOffset;
  }

  subscribeGlobal() {
    // Every operator input, whatever its door (other consoles, REST, speech, rosbridge, a
    // replay: the operator's, as recorded), before the replies: a latched one arrives first,
    // then the reply it annotates.
    this.ros.subscribe("/console/utterance", TOPIC_TYPES["/console/utterance"], (m) =>
      this.dialog.onUtterance(m),
    );
    this.ros.subscribe("/console/reply", TOPIC_TYPES["/console/reply"], (m) => {
      this.dialog.onReply(m);
      this.onAlarm(m);
    });
    this.ros.subscribe("/console/state", TOPIC_TYPES["/console/state"], (m) => {
      if (!m.drone || !this.fleet || m.drone === this.drone) this.dialog.onState(m);
    });
    this.ros.subscribe("/fleet/status", TOPIC_TYPES["/fleet/status"], (m) => this.onFleet(m), {
      throttle_rate: 200,
    });
    // 5 Hz is enough to call the road down after 1 s of silence.
    this.ros.subscribe(SERVER_HEARTBEAT, "std_msgs/String", () => this.onServerBeat(), {
      throttle_rate: 200,
    });
  }

  onServerBeat() {
    this.serverBeatAt = performance.now();
    this.freshness.beat("server");
    if (this.serverStalled) this.checkRoads();
  }

  /** A drone's safety door as GET /drones tells it: its URL and this pilot's ticket. */
  learnDoor(name, vehicle) {
    // Without a ticket (a vehicle this console did not spawn) a pilot opens it with the token.
    this.doors.learn(name, vehicle, this.role === "pilot" ? this.token : null);
  }

  /**
   * Both roads' health, every 250 ms: the server's heartbeat and the selected drone's door.
   * A road silent for 1 s turns red, and the connection pill never says "Connected" while the
   * server is stalled.
   */
  checkRoads() {
    const now = performance.now();
    const open = this.ros.state === STATES.OPEN;
    // `uav-console replay` plays recorded heartbeats: a paused replay is not a stalled server.
    const replay = !$("replay-bar").hidden;
    const silentMs = this.serverBeatAt === null ? Infinity : now - this.serverBeatAt;
    const stalled = open && !replay && silentMs > DOOR_DEAD_MS;
    if (stalled !== this.serverStalled) {
      this.serverStalled = stalled;
      this.onConnState(this.ros.state);
    }
    let server = { text: "ok", level: "ok" };
    if (!open) server = { text: "down", level: "alert" };
    else if (stalled) server = { text: `silent ${(silentMs / 1000).toFixed(1)} s`, level: "alert" };
    const door = this.drone ? this.doors.get(this.drone) : null;
    let road = { text: "none", level: "unknown" }; // inline drones have no door
    if (door && door.healthy(now)) road = { text: "ok", level: "ok" };
    else if (door && door.authenticated) {
      road = { text: `silent ${((now - door.lastBeat) / 1000).toFixed(1)} s`, level: "alert" };
    } else if (door) road = { text: "down", level: "alert" };
    this.status.setRoads(server, road);
    document.body.dataset.serverRoad = server.level;
    document.body.dataset.doorRoad = road.level;
  }

  /** ANS alarms (Reply.alarm) raise the banner that waits for an acknowledgement. */
  onAlarm(m) {
    const alarm = m.alarm || "";
    if (!alarm || (this.fleet && m.drone && m.drone !== this.drone && m.level !== "alert")) return;
    const who = this.fleet && m.drone ? `${m.drone}: ` : "";
    if (alarm === "link") this.alertBanner.drop(`${m.drone}:link-rest`); // one banner per event
    // Stamped when the drone raised it (a replay's: the recording's time, not today's).
    const at = new Date((stampSeconds(m.header?.stamp) ?? this.pageNow()) * 1000);
    if (m.level === "alert" || m.level === "warn") this.alertBanner.raise(`${m.drone}:${alarm}`, `${who}${m.text}`, at);
    else this.alertBanner.clear(`${m.drone}:${alarm}`, `${who}${m.text}`);
  }

  onFleet(msg) {
    this.freshness.beat("fleet");
    this.map.onFleet(msg);
    const ul = $("fleet-list");
    const items = (msg.drones || []).map((d) => {
      const li = document.createElement("li");
      const bat = Number.isFinite(d.battery) ? `${Math.round(d.battery)} %` : "–";
      // One flight-state label everywhere; the patrol role only while it means something.
      const flight = d.name === this.drone && this.status.view.flight ? this.status.view.flight : flightLabel(d.state);
      const role = ["patrolling", "relieving", "returning"].includes(d.role) ? ` · ${d.role}` : "";
      li.textContent = `${d.name} · ${flight}${role} · ${bat}`;
      if (d.link === false) {
        li.dataset.stale = "true";
        li.textContent += " · no link";
      }
      return li;
    });
    ul.replaceChildren(...items);
  }

  async pollDrone(force = false) {
    // While the socket is down the server is too: no REST polling (and no console noise).
    if (!this.drone || (document.hidden && !force) || this.ros.state !== STATES.OPEN) return;
    try {
      const asked = this.drone;
      const status = await this.api.drone(asked);
      if (asked === this.drone) this.judgeSnapshot(status);
      // A drone in its own vehicle process has a safety door: stops that no web traffic delays.
      this.learnDoor(this.drone, status.vehicle);
      this.telemetry.onDroneStatus(status);
      this.training.setSimulated(this.drone, status.simulated);
      this.map.onSnapshot(this.drone, status);
      this.map.setLocalised(this.drone, status.localised);
      this.status.setTask(status.task || null);
      if (Number.isFinite(status.battery_pct)) this.status.setBattery(status.battery_pct);
      // The dialog's link alarm says it first; this covers a server without one (a replay).
      // The freshness alarm names the cause (a vehicle process that does not answer) already.
      const ansSaidIt = this.alertBanner.active.some(
        (x) => x.key === `${this.drone}:link` || x.key === `fresh:vehicle:${this.drone}`,
      );
      if (status.link_ok === false && !ansSaidIt) {
        const at = new Date(this.pageNow() * 1000);
        this.alertBanner.raise(`${this.drone}:link-rest`, `${this.drone}: the link to the drone is lost.`, at);
      } else if (status.link_ok === true) {
        this.alertBanner.clear(`${this.drone}:link-rest`, `${this.drone}: the link to the drone is back.`);
      }
    } catch {
      /* the connection pill already tells the operator */
    }
  }

  /**
   * The REST snapshot's own age: fresh data from the vehicle counts as a word from it (a drone
   * with no navdata topic, a MAVLink one, has no other); and why it is silent, when it is. A
   * new vehicle process (another pid: the old one died and serve restarted it) is said even
   * when it spoke again before the page's alarm was due.
   */
  judgeSnapshot(status) {
    if (!status || typeof status !== "object") return;
    const v = status.vehicle && typeof status.vehicle === "object" ? status.vehicle : null;
    const pid = Number.isInteger(v?.pid) ? v.pid : null;
    if (pid !== null) {
      const known = this.vehiclePid;
      if (known && known.drone === this.drone && known.pid !== pid) {
        this.freshness.replaced("vehicle", "its vehicle process was restarted");
      }
      this.vehiclePid = { drone: this.drone, pid };
    }
    const gone = v?.connected === false;
    let why = "";
    if (gone) why = "its vehicle process does not answer";
    else if (status.link_ok === false) why = "the link to the drone is lost";
    this.freshness.setWhy("vehicle", why);
    const nav = Number(status.navdata_age_s);
    const hop = Number(v?.age_s);
    const age = (Number.isFinite(nav) ? nav : 0) + (Number.isFinite(hop) ? hop : 0);
    if (!gone && status.link_ok !== false) this.freshness.beat("vehicle", performance.now() / 1000 - age);
  }

  // ---- commands ----------------------------------------------------------------------------
  /** Publish what the operator said/typed to /console/utterance; false if it could not be sent. */
  sendUtterance(text, source, confidence, drone = this.drone) {
    this.supersedeStops(); // a newer command: a pending stop must not fire after it
    // asked_by: a bare yes or no answers the drone that asked, whichever is selected.
    const askedBy = this.dialog.askedBy(drone || "");
    const msg = { text, confidence, source, drone: drone || "", asked_by: askedBy };
    const type = TOPIC_TYPES["/console/utterance"];
    const id = this.ros.publish("/console/utterance", type, msg, { issued: this.serverNow() });
    if (!id) {
      this.flash("Not connected: the command was not sent.", "alert");
      return false;
    }
    this.dialog.addUtterance(text, { source, confidence, drone: drone || "" });
    return true;
  }

  publishTwist(twist) {
    if (!this.drone) return;
    if (!isZeroTwist(twist)) this.supersedeStops(); // jogging again drops a pending stop
    const topic = droneTopic("/cmd_vel", this.drone, this.fleet);
    if (!this.ros.publish(topic, TOPIC_TYPES["/cmd_vel"], twist, { issued: this.serverNow() })) {
      this.flash("Not connected: jog not sent.", "alert");
    }
  }

  /**
   * Direct actions. Land, Hover and Emergency go down both roads at once (stops.js); any other
   * action is a newer command, which drops a stop still pending (nothing fires from the past).
   */
  async act(action, source = "button") {
    if (!this.drone) return;
    if (STOP_ACTIONS.includes(action)) {
      if (action === "emergency") {
        this.dialog.addSystem(`EMERGENCY STOP (${source === "keyboard" ? "Shift+Esc" : "button"})`);
        document.body.dataset.emergency = String(Date.now());
      }
      this.stops.send(this.drone, action, source);
      return;
    }
    if (action === "takeoff" && this.airborne()) {
      // As the dialog answers a typed "take off": said on the button, nothing sent.
      this.controls.say("btn-takeoff", "I am already flying.");
      this.dialog.addSystem(`Take off (${source}): I am already flying.`);
      return;
    }
    this.supersedeStops();
    try {
      const res = await this.api.action(this.drone, action, source);
      // A refusal is shown where the operator looks (the banner) with its reason and the way
      // out; the server also says it in the dialog (and aloud).
      if (res && res.accepted === false) this.flash(res.detail || `${action} refused`, "warn", "refusal");
    } catch (err) {
      this.flash(`${action} failed: ${err.message}`, "alert");
      if (err.status === 403) this.onStatus({ level: "error", msg: err.message });
    }
  }

  /** In the air by the page's fresh word on it (a stale state decides nothing). */
  airborne() {
    if (this.freshness.staleAge("vehicle") !== null) return false;
    return AIRBORNE.includes(this.status.view.flight);
  }

  /** A newer operator command: stops still pending are dropped (the page says so). */
  supersedeStops() {
    return this.stops.supersede();
  }

  /** Where a stop stands, where the operator looks: a standing banner while it is pending. */
  onStopChange(stop) {
    const { text, level } = stopText(stop, this.clockOffset);
    document.body.dataset.stop = stop.state;
    document.body.dataset.stopText = text;
    if (stop.state === "pending") {
      if (!stop.announced) this.dialog.addSystem(text);
      stop.announced = true;
      this.banner(text, "alert", "stop");
      return;
    }
    this.dialog.addSystem(text);
    if ($("banner").dataset.source === "stop") this.banner(null);
    this.flash(text, level, "stop");
  }

  /** Scene description (the server's captioner), shown and spoken like a reply. */
  async describe() {
    if (!this.drone) return;
    const btn = $("describe");
    btn.disabled = true;
    try {
      const res = await this.api.post(`/drones/${encodeURIComponent(this.drone)}/describe`, {});
      this.dialog.onReply({ text: res.text, level: "info", speak: true });
    } catch (err) {
      this.dialog.onReply({ text: `I cannot describe the scene: ${err.message}`, level: "warn", speak: true });
    } finally {
      btn.disabled = false;
    }
  }

  async goToMarker(id) {
    const text = `go to marker ${id}`;
    this.supersedeStops();
    this.dialog.addUtterance(text, { source: "map", drone: this.drone || "" });
    try {
      const res = await this.api.command(text, { drone: this.drone || undefined });
      // The reply also arrives on /console/reply; show REST-only refusals here.
      if (res && res.accepted === false && res.reply) this.flash(res.reply, "warn");
    } catch (err) {
      this.flash(`Could not send “${text}”: ${err.message}`, "alert");
    }
  }

  /** Esc: close what is open (popover, passing banner, shortcuts list); true if something was. */
  closeOpen() {
    if (!$("map-popover").hidden) {
      this.map.hidePopover();
      $("map").focus();
      return true;
    }
    const b = $("banner");
    if (!b.hidden && b.dataset.source !== "rest" && b.dataset.source !== "lease") {
      this.banner(null);
      return true;
    }
    const details = document.querySelector(".shortcuts[open]");
    if (details) {
      details.open = false;
      return true;
    }
    return false;
  }

  /** Which voice speaks replies: the browser's, the server's (espeak-ng), or none (said so). */
  async checkVoice() {
    const voices = await checkVoices(window.speechSynthesis);
    if (voices > 0) {
      this.dialog.setVoice("browser");
      return;
    }
    try {
      const r = await fetch("/api/v1/tts?text=ok", {
        headers: { Authorization: `Bearer ${this.token}` },
        cache: "no-store",
      });
      this.dialog.setVoice(r.ok ? "server" : "none");
    } catch {
      this.dialog.setVoice("none");
    }
  }

  /** Stop the console's voice now: the reply playing and those queued behind it (the operator
   *  interrupts it to speak: voice.js interrupt). They stay on screen. */
  hush() {
    this.hushedAt = performance.now();
    window.speechSynthesis?.cancel();
    try {
      this.voiceSource?.stop();
    } catch {
      /* not started, or already ended */
    }
  }

  /** Play ``text`` spoken by the server (GET /api/v1/tts), one reply after another. */
  serverSpeak(text) {
    const queuedAt = performance.now();
    this.speechQueue = (this.speechQueue || Promise.resolve()).then(async () => {
      if (queuedAt < (this.hushedAt ?? -1)) return; // interrupted before its turn
      try {
        const r = await fetch(`/api/v1/tts?text=${encodeURIComponent(text.slice(0, 400))}`, {
          headers: { Authorization: `Bearer ${this.token}` },
          cache: "no-store",
        });
        if (!r.ok) return;
        // Web Audio, not an <audio> element with a blob: URL: nothing a Content-Security-Policy
        // must allow beyond fetching from this origin.
        const Ctx = window.AudioContext || window.webkitAudioContext;
        if (!Ctx) return;
        this.audioCtx = this.audioCtx || new Ctx();
        if (this.audioCtx.state === "suspended") await this.audioCtx.resume().catch(() => {});
        const buffer = await this.audioCtx.decodeAudioData(await r.arrayBuffer());
        if (queuedAt < (this.hushedAt ?? -1)) return;
        const src = this.audioCtx.createBufferSource();
        src.buffer = buffer;
        src.connect(this.audioCtx.destination);
        this.voiceSource = src;
        this.spokenByServer = (this.spokenByServer || 0) + 1;
        this.serverSpeaking += 1;
        try {
          await new Promise((resolve) => {
            src.onended = resolve;
            src.start();
            // A suspended context (no user gesture yet) never ends: do not hold the queue.
            setTimeout(resolve, (buffer.duration + 1) * 1000);
          });
        } finally {
          this.serverSpeaking -= 1;
        }
      } catch {
        /* speech is a convenience: the reply is on screen */
      }
    });
  }

  // ---- feedback ------------------------------------------------------------------------------
  notice(text) {
    this.dialog.addSystem(text);
    $("interim").textContent = text;
  }

  banner(text, level = "alert", source = "") {
    const b = $("banner");
    if (!text) {
      b.hidden = true;
      b.textContent = "";
      b.dataset.source = "";
      return;
    }
    b.textContent = text;
    b.dataset.level = level;
    b.dataset.source = source;
    b.hidden = false;
  }

  flash(text, level, source = "flash") {
    // A standing alert about the token outranks passing messages.
    if ($("banner").dataset.source === "rest" && !$("banner").hidden) {
      this.dialog.addSystem(text);
      return;
    }
    this.banner(text, level, source);
    clearTimeout(this.flashTimer);
    // A refusal stays long enough to be read under pressure; Esc closes it sooner.
    this.flashTimer = setTimeout(() => {
      if ($("banner").dataset.source === source) this.banner(null);
    }, source === "refusal" ? 12000 : 5000);
  }

  /** Phones: the fixed dock's and the floating messages' heights in --dock-h and --msgs-h, so
   *  the last panel is not hidden under them; the top bar's in --top-h, a replay's timeline's
   *  in --replay-h (a phone on its side fits the camera under both). */
  layoutDock() {
    const root = document.documentElement.style;
    const px = (el) => `${Math.ceil(el.getBoundingClientRect().height)}px`;
    root.setProperty("--dock-h", px($("dock")));
    const msgs = $("messages");
    root.setProperty("--msgs-h", getComputedStyle(msgs).position === "fixed" ? px(msgs) : "0px");
    root.setProperty("--top-h", px(document.querySelector(".topbar")));
    root.setProperty("--replay-h", $("replay-bar").hidden ? "0px" : px($("replay-bar")));
  }
}

function isZeroTwist(t) {
  const parts = [t?.linear, t?.angular];
  return parts.every((v) => !v || (!v.x && !v.y && !v.z));
}

const app = new Console();
window.uavConsole = app; // for debugging from the browser's console and for the browser tests
app.start();
