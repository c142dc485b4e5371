// Map panel on Leaflet (web/static/vendor/leaflet, 1.9.4): the world (the room's plan indoors;
// outdoors a basemap from the operator's tile server, or the plain local grid when no tiles
// load) with every drone's estimated pose, heading, trail and current target. Zoom and pan by
// wheel, pinch, the +/- buttons or keys; "Fit" frames the fleet and its route.
//
// Map frame per docs/CONVENTIONS.md: x east / along the room, y north / across it, metres.
// Indoors (and outdoors without a GPS origin) Leaflet's CRS.Simple in metres: LatLng(y, x).
// Outdoors with a GPS origin, Web Mercator: the local east/north offsets become latitude and
// longitude on the WGS-84 ellipsoid's local radii (exact to millimetres over a 1 km field),
// so the drones sit on the tiles where they are.
//
// Labels never overlap: after every move, zoom or change, each label (drones first, then the
// target, markers, stations, waypoints) takes the first of a few places beside its point that
// no placed label covers, or is hidden until there is room (zoom in).

import * as L from "../vendor/leaflet/leaflet-src.esm.js";
import { flightLabel } from "./status.js";
import { quaternionYaw } from "./util.js";

const TRAIL_LEN = 400;
const HIT_PX = 16;
// WGS-84 (NIMA TR8350.2): semi-major axis and first eccentricity squared.
const WGS84_A = 6378137.0;
const WGS84_E2 = 6.69437999014e-3;
const OSM_HOST = "tile.openstreetmap.org";
// Where a label may sit, relative to its point (px): right, left, above, below, diagonals.
const SPOTS = [
  [13, -7],
  [-13, -7, "left"],
  [0, -25, "center"],
  [0, 12, "center"],
  [11, -22],
  [-11, -22, "left"],
  [11, 8],
  [-11, 8, "left"],
];
const ICON_HALF_PX = { drone: 10, marker: 6 }; // what a label may not cover of a drone, a marker
const DECLUTTER_MS = 150;

/** The tile URL template the server set (``UAVC_TILE_URL``; "" = tiles off). */
export function pageTileUrl(doc = document) {
  return doc.querySelector('meta[name="uavc-tile-url"]')?.content?.trim() || "";
}

/**
 * Local east/north metres <-> LatLng for a world: CRS.Simple metres, or geodetic around the
 * world's GPS origin (meridian and prime-vertical radii of curvature at its latitude).
 */
export class Frame {
  constructor(world) {
    const o = world?.gps_origin;
    this.geo = !!o && Number.isFinite(o.lat) && Number.isFinite(o.lon);
    if (this.geo) {
      const phi = (o.lat * Math.PI) / 180;
      const w = 1 - WGS84_E2 * Math.sin(phi) ** 2;
      this.lat0 = o.lat;
      this.lon0 = o.lon;
      this.mPerDegLat = ((WGS84_A * (1 - WGS84_E2)) / w ** 1.5) * (Math.PI / 180);
      this.mPerDegLon = (WGS84_A / Math.sqrt(w)) * Math.cos(phi) * (Math.PI / 180);
    }
  }

  latLng(x, y) {
    if (!this.geo) return L.latLng(y, x);
    return L.latLng(this.lat0 + y / this.mPerDegLat, this.lon0 + x / this.mPerDegLon);
  }

  xy(latlng) {
    if (!this.geo) return { x: latlng.lng, y: latlng.lat };
    return { x: (latlng.lng - this.lon0) * this.mPerDegLon, y: (latlng.lat - this.lat0) * this.mPerDegLat };
  }
}

export class MapPanel {
  /**
   * @param {HTMLElement} container the #map element (Leaflet's container)
   * @param {{popover: HTMLElement, text: HTMLElement, go: HTMLButtonElement, cancel: HTMLButtonElement,
   *          caption: HTMLElement, focus?: HTMLElement}} els
   * @param {(markerId: number) => void} onGo called when the operator picks "Go there"
   * @param {{tileUrl?: string}} options
   */
  constructor(container, els, onGo, options = {}) {
    this.container = container;
    this.els = els;
    this.onGo = onGo;
    this.tileUrl = options.tileUrl ?? pageTileUrl();
    this.world = null;
    this.frame = new Frame(null);
    this.selected = null; // drone name whose pose comes from /uav/pose
    /** name -> {x, y, yaw, role, battery, trail: [[x,y]|null ...], layers} */
    this.drones = new Map();
    this.targetMarker = null;
    this.visibleMarkers = new Set();
    this.visibleAt = 0;
    this.popoverMarker = null;
    this.keyIndex = -1;
    this.dirty = true;
    this.labelsDirty = true;
    this.lastDeclutter = 0;
    this.viewTouched = false; // the operator zoomed or panned: no refit on resize
    this.tiles = null;
    this.tileState = "off";
    this.map = null;
    this.labels = []; // {el, priority, latlng}
    this.renders = 0;

    container.addEventListener("keydown", (ev) => this.onKey(ev));
    els.go.addEventListener("click", () => {
      if (this.popoverMarker !== null) this.onGo(this.popoverMarker);
      this.hidePopover();
    });
    els.cancel.addEventListener("click", () => this.hidePopover());
    new ResizeObserver(() => this.resize()).observe(container);
    const loop = () => {
      if (this.dirty) this.draw();
      else if (this.labelsDirty && performance.now() - this.lastDeclutter > DECLUTTER_MS) this.declutter();
      requestAnimationFrame(loop);
    };
    requestAnimationFrame(loop);
  }

  // ---- world ---------------------------------------------------------------------------------

  setWorld(world) {
    const key = JSON.stringify(world);
    if (key === this.worldKey && this.map) return; // a reconnection: keep the view
    this.worldKey = key;
    this.world = world;
    this.frame = new Frame(world);
    const kind = world.kind || (world.gps_origin ? "outdoor" : "indoor");
    const b = world.bounds || {};
    const size = `${fmtM(b.x_max - b.x_min)} × ${fmtM(b.y_max - b.y_min)} m`;
    this.els.caption.textContent = `${world.name || kind} · ${size}`;
    this.build();
    this.dirty = true;
  }

  get outdoor() {
    const w = this.world || {};
    return (w.kind || "") === "outdoor" || !!w.gps_origin;
  }

  /** (Re)create the Leaflet map and the world's layers. */
  build() {
    if (this.map) {
      this.map.remove();
      for (const d of this.drones.values()) d.layers = null;
    }
    this.labels = [];
    const geo = this.frame.geo;
    const map = L.map(this.container, {
      crs: geo ? L.CRS.EPSG3857 : L.CRS.Simple,
      zoomSnap: 0.25,
      zoomDelta: 0.5,
      wheelPxPerZoomLevel: 90,
      minZoom: geo ? 12 : -1,
      maxZoom: geo ? 22 : 8,
      keyboard: false, // arrows pick markers here (onKey); +/- zoom
      attributionControl: false,
      zoomControl: true,
      boxZoom: false,
    });
    this.map = map;
    this.fitInterest(false); // a view first: Leaflet renders no layer before it has one
    this.container.classList.add("uav-map");
    this.container.dataset.crs = geo ? "geo" : "metres";
    L.control.scale({ metric: true, imperial: false, maxWidth: 120 }).addTo(map);
    this.addFitControl(map);
    this.attribution = L.control.attribution({ prefix: false }).addTo(map);

    // Panes: tiles < grid < world < trails < drones < labels.
    map.createPane("grid").style.zIndex = "250";
    map.createPane("world").style.zIndex = "400";
    map.createPane("trails").style.zIndex = "450";
    map.createPane("drones").style.zIndex = "600";
    map.createPane("labels").style.zIndex = "650";
    for (const p of ["grid", "world", "trails", "labels"]) map.getPane(p).style.pointerEvents = "none";

    this.setupTiles(map);
    this.grid = L.layerGroup([], { pane: "grid" }).addTo(map);
    this.drawGrid();
    this.drawWorld(map);
    this.rings = {
      seen: L.layerGroup().addTo(map),
      target: L.layerGroup().addTo(map),
    };
    map.on("click", (ev) => this.onClick(ev));
    map.on("zoomstart movestart", () => this.hidePopoverPosition());
    map.on("zoomend moveend resize", () => {
      this.labelsDirty = true;
      this.placePopover();
    });
    map.on("dragstart zoomstart", () => {
      // a zoom of our own (fit, first view) is not the operator's
      if (!this.fitting) this.viewTouched = true;
    });
  }

  addFitControl(map) {
    const Fit = L.Control.extend({
      options: { position: "topleft" },
      onAdd: () => {
        const bar = L.DomUtil.create("div", "leaflet-bar map-fit");
        const a = L.DomUtil.create("a", "", bar);
        a.href = "#";
        a.setAttribute("role", "button");
        a.textContent = "⤢";
        a.title = "Fit the fleet and its route (F)";
        a.setAttribute("aria-label", "Fit the fleet and its route");
        L.DomEvent.disableClickPropagation(bar);
        L.DomEvent.on(a, "click", (ev) => {
          L.DomEvent.preventDefault(ev);
          this.fitInterest(true);
        });
        return bar;
      },
    });
    new Fit().addTo(map);
  }

  setupTiles(map) {
    this.tiles = null;
    this.tileState = "off";
    if (this.frame.geo && this.tileUrl) {
      const osm = this.tileUrl.includes(OSM_HOST);
      let host = "";
      try {
        host = new URL(this.tileUrl.replace("{s}", "a")).host;
      } catch {
        /* the server checked it; a bad one simply loads nothing */
      }
      const attribution = osm
        ? '© <a href="https://www.openstreetmap.org/copyright" rel="noopener">OpenStreetMap</a> contributors'
        : `Tiles: ${escapeHtml(host)}`;
      this.tiles = L.tileLayer(this.tileUrl, {
        maxNativeZoom: 19,
        maxZoom: 22,
        attribution,
        crossOrigin: false,
        referrerPolicy: "no-referrer",
      });
      this.tileState = "loading";
      this.tiles.on("tileload", () => this.setTileState("loaded"));
      this.tiles.on("tileerror", () => {
        if (this.tileState !== "loaded") this.setTileState("failed");
      });
      this.tiles.addTo(map);
    }
    this.container.dataset.tiles = this.tileState;
  }

  setTileState(state) {
    if (this.tileState === state) return;
    this.tileState = state;
    this.container.dataset.tiles = state;
    this.drawGrid();
  }

  /** The plain local grid: 1 m indoors, 10 m outdoors; outdoors only while no tiles show. */
  drawGrid() {
    if (!this.grid || !this.world) return;
    this.grid.clearLayers();
    const tilesShow = this.tileState === "loaded";
    this.container.dataset.grid = tilesShow ? "off" : "on";
    if (tilesShow) return;
    const b = this.world.bounds;
    const step = this.outdoor ? 10 : 1;
    const f = this.frame;
    const opts = { pane: "grid", className: "map-grid", weight: 1, interactive: false };
    for (let x = Math.ceil(b.x_min / step) * step; x <= b.x_max + 1e-9; x += step) {
      this.grid.addLayer(L.polyline([f.latLng(x, b.y_min), f.latLng(x, b.y_max)], opts));
    }
    for (let y = Math.ceil(b.y_min / step) * step; y <= b.y_max + 1e-9; y += step) {
      this.grid.addLayer(L.polyline([f.latLng(b.x_min, y), f.latLng(b.x_max, y)], opts));
    }
  }

  drawWorld(map) {
    const w = this.world;
    const f = this.frame;
    const b = w.bounds;
    const pane = "world";
    const corners = [
      f.latLng(b.x_min, b.y_min),
      f.latLng(b.x_max, b.y_min),
      f.latLng(b.x_max, b.y_max),
      f.latLng(b.x_min, b.y_max),
    ];
    // walls (indoor) or the field's boundary (outdoor)
    L.polygon(corners, {
      pane,
            className: this.outdoor ? "map-fence" : "map-wall",
      fill: false,
      weight: this.outdoor ? 1.5 : 3,
      interactive: false,
    }).addTo(map);
    // furniture and other objects, faintly (rotated footprints)
    for (const o of w.objects || []) {
      if (!o.position) continue;
      const hw = (o.size?.w ?? 0.3) / 2;
      const hd = (o.size?.d ?? 0.3) / 2;
      const a = ((o.yaw_deg || 0) * Math.PI) / 180;
      const pts = [
        [-hw, -hd],
        [hw, -hd],
        [hw, hd],
        [-hw, hd],
      ].map(([u, v]) =>
        f.latLng(o.position.x + u * Math.cos(a) - v * Math.sin(a), o.position.y + u * Math.sin(a) + v * Math.cos(a)),
      );
      L.polygon(pts, { pane, className: "map-object", weight: 1, interactive: false }).addTo(map);
    }
    // waypoints (outdoor patrol route)
    const wps = w.waypoints || [];
    if (wps.length) {
      L.polygon(
        wps.map((p) => f.latLng(p.position.x, p.position.y)),
        { pane, className: "map-route", fill: false, weight: 1.5, dashArray: "4 3", interactive: false },
      ).addTo(map);
      for (const p of wps) {
        const ll = f.latLng(p.position.x, p.position.y);
        L.marker(ll, { pane, icon: icon("map-waypoint", '<span class="diamond"></span>', 14), interactive: false, keyboard: false }).addTo(map);
        this.addLabel(map, ll, String(p.id), 5, "waypoint");
      }
    }
    // stations (home pads)
    for (const s of w.stations || []) {
      const ll = f.latLng(s.position.x, s.position.y);
      L.marker(ll, { pane, icon: icon("map-station", "H", 16), interactive: false, keyboard: false }).addTo(map);
      this.addLabel(map, ll, String(s.id), 4, "station");
    }
    // markers: a square with a tick along the direction it faces, and its id
    this.markerIcons = new Map();
    for (const m of w.markers || []) {
      const ll = f.latLng(m.position.x, m.position.y);
      const yaw = m.yaw_rad ?? ((m.yaw_deg || 0) * Math.PI) / 180;
      const mk = L.marker(ll, {
        pane,
        icon: icon("map-marker", '<span class="square"></span><span class="tick"></span>', 26),
        interactive: false,
        keyboard: false,
      }).addTo(map);
      const el = mk.getElement();
      el.dataset.marker = String(m.id);
      el.querySelector(".tick").style.transform = `rotate(${-yaw}rad)`;
      this.markerIcons.set(m.id, el);
      this.addLabel(map, ll, String(m.id), 3, "marker", m.id);
    }
  }

  addLabel(map, latlng, text, priority, kind, id = null) {
    const m = L.marker(latlng, {
      pane: "labels",
      icon: L.divIcon({ className: "map-label-anchor", html: "", iconSize: [0, 0] }),
      interactive: false,
      keyboard: false,
    }).addTo(map);
    const el = document.createElement("span");
    el.className = "map-label";
    el.dataset.kind = kind;
    if (id !== null) el.dataset.id = String(id);
    el.textContent = text;
    m.getElement().append(el);
    const label = { el, marker: m, priority, kind, id, w: 0, h: 0 };
    this.labels.push(label);
    this.labelsDirty = true;
    return label;
  }

  /** Frame the fleet and its route (drones, waypoints, stations, markers); the room indoors. */
  fitInterest(animate = true) {
    if (!this.map || !this.world) return;
    const f = this.frame;
    const pts = [];
    if (this.outdoor) {
      for (const d of this.drones.values()) if (d.x !== null) pts.push(f.latLng(d.x, d.y));
      for (const p of this.world.waypoints || []) pts.push(f.latLng(p.position.x, p.position.y));
      for (const s of this.world.stations || []) pts.push(f.latLng(s.position.x, s.position.y));
      for (const m of this.world.markers || []) pts.push(f.latLng(m.position.x, m.position.y));
    }
    const b = this.world.bounds;
    if (pts.length < 2) pts.push(f.latLng(b.x_min, b.y_min), f.latLng(b.x_max, b.y_max));
    const bounds = L.latLngBounds(pts);
    this.fitting = true;
    try {
      this.map.invalidateSize(false);
      this.map.fitBounds(bounds.pad(this.outdoor ? 0.08 : 0.02), { animate, padding: [6, 6] });
    } finally {
      this.fitting = false;
    }
    this.viewTouched = false;
    this.labelsDirty = true;
  }

  /** Forget every drone's trail (a replay jumped in time). */
  clearTrails() {
    for (const d of this.drones.values()) d.trail = [];
    this.dirty = true;
  }

  setSelected(name) {
    this.selected = name;
    this.dirty = true;
  }

  drone(name) {
    let d = this.drones.get(name);
    if (!d) {
      d = { x: null, y: null, yaw: 0, role: "", battery: null, trail: [], layers: null };
      this.drones.set(name, d);
    }
    return d;
  }

  // ---- data in (same interface as the panels: rosbridge messages and REST snapshots) -------

  /** geometry_msgs/PoseStamped of ``name`` (the EKF estimate). */
  onPose(name, msg, live = true) {
    const p = msg?.pose?.position;
    if (!p || !Number.isFinite(p.x) || !Number.isFinite(p.y)) return;
    const d = this.drone(name);
    if (live) d.poseAt = performance.now();
    // Before the first marker fix the estimate is a guess: keep it off the trail.
    const guess = d.localised === false;
    d.x = p.x;
    d.y = p.y;
    d.z = p.z;
    d.yaw = quaternionYaw(msg.pose.orientation);
    if (!guess) pushTrail(d, p.x, p.y);
    this.dirty = true;
  }

  /**
   * The REST snapshot's estimate (x, y, yaw_rad, localised), used only while /uav/pose is
   * silent, so the map still shows the drone when the topic is not flowing.
   */
  onSnapshot(name, st) {
    const d = this.drone(name);
    if (performance.now() - (d.poseAt || 0) < 1500) return;
    if (!st || st.localised === false || !Number.isFinite(st.x) || !Number.isFinite(st.y)) return;
    this.onPose(
      name,
      {
        pose: {
          position: { x: st.x, y: st.y, z: st.z ?? 0 },
          orientation: { x: 0, y: 0, z: Math.sin((st.yaw_rad || 0) / 2), w: Math.cos((st.yaw_rad || 0) / 2) },
        },
      },
      false,
    );
  }

  /** Whether the estimator knows where the drone is (REST ``localised``); unknown is null. */
  setLocalised(name, localised) {
    const d = this.drone(name);
    const v = typeof localised === "boolean" ? localised : null;
    if (d.localised !== v) {
      d.localised = v;
      this.dirty = true;
    }
  }

  /** The selected drone's flight state, as the status bar says it (labels agree). */
  setFlightLabel(name, label) {
    if (!name) return;
    const d = this.drone(name);
    if (d.flight !== label) {
      d.flight = label;
      d.flightLive = true;
      this.dirty = true;
    }
  }

  /** uav_console/FleetStatus: every drone with its role. */
  onFleet(msg) {
    for (const s of msg?.drones || []) {
      const d = this.drone(s.name);
      d.role = s.role || "";
      if (!(s.name === this.selected && d.flightLive)) d.flight = flightLabel(s.state);
      d.battery = s.battery;
      d.link = s.link;
      // The fleet status is coarse; the selected drone's pose topic is fresher.
      if (s.name !== this.selected && s.position && Number.isFinite(s.position.x)) {
        d.x = s.position.x;
        d.y = s.position.y;
        d.yaw = ((s.yaw_deg || 0) * Math.PI) / 180;
        pushTrail(d, d.x, d.y);
      }
    }
    this.dirty = true;
  }

  /** uav_console/MarkerArray: the markers the camera sees now (ringed on the map). */
  onMarkers(msg) {
    const ids = new Set((msg?.markers || []).map((m) => m.id));
    const same = ids.size === this.visibleMarkers.size && [...ids].every((i) => this.visibleMarkers.has(i));
    this.visibleMarkers = ids;
    this.visibleAt = performance.now();
    if (!same) this.dirty = true;
  }

  /** uav_console/TaskStatus: remember a marker target ("goto" / "marker 3") to highlight. */
  onTask(msg) {
    const text = `${msg?.name || ""} ${msg?.detail || ""}`;
    const m = /marker\D{0,3}(\d+)/i.exec(text);
    const active = !/(done|succeeded|failed|cancel|idle)/i.test(msg?.state || "");
    const next = m && active ? Number(m[1]) : null;
    if (next !== this.targetMarker) {
      this.targetMarker = next;
      this.dirty = true;
    }
  }

  resize() {
    if (!this.map) return;
    const rect = this.container.getBoundingClientRect();
    if (rect.width < 2) return;
    this.map.invalidateSize(false);
    if (!this.viewTouched) this.fitInterest(false);
    this.labelsDirty = true;
  }

  // ---- drawing -------------------------------------------------------------------------------

  draw() {
    this.dirty = false;
    if (!this.map || !this.world) return;
    const f = this.frame;
    // markers the camera sees now, the target and the picked one
    const seenFresh = performance.now() - this.visibleAt < 1000;
    for (const [id, el] of this.markerIcons || []) {
      el.classList.toggle("seen", seenFresh && this.visibleMarkers.has(id));
      el.classList.toggle("target", id === this.targetMarker);
      el.classList.toggle("picked", id === this.popoverMarker);
    }
    if (seenFresh && this.visibleMarkers.size) setTimeout(() => (this.dirty = true), 1000);
    for (const label of this.labels) {
      if (label.kind !== "marker") continue;
      const p = label.id === this.targetMarker || label.id === this.popoverMarker ? 2 : 3;
      if (label.priority !== p) {
        label.priority = p;
        this.labelsDirty = true;
      }
    }
    // drones: trail, body (arrow along the heading), label
    for (const [name, d] of this.drones) {
      if (d.x === null) continue;
      if (!d.layers) d.layers = this.droneLayers(name);
      const ll = f.latLng(d.x, d.y);
      const mine = name === this.selected;
      const lost = d.localised === false;
      d.layers.body.setLatLng(ll);
      const el = d.layers.body.getElement();
      if (el) {
        el.classList.toggle("mine", mine);
        el.classList.toggle("lost", lost);
        el.querySelector("svg").style.transform = `rotate(${-d.yaw}rad)`;
      }
      d.layers.trail.setLatLngs(trailLines(d.trail, f));
      d.layers.trail.getElement?.()?.classList.toggle("mine", mine);
      // The flight state (same words as the status bar), and the patrol role only while it
      // means something: "idle" in flight or "lost" after a stop would contradict the bar.
      let text = d.flight ? `${name} · ${d.flight}` : name;
      if (["patrolling", "relieving", "returning"].includes(d.role)) text += ` · ${d.role}`;
      if (lost) text += " · not localised";
      const label = d.layers.label;
      label.marker.setLatLng(ll);
      if (label.el.textContent !== text) {
        label.el.textContent = text;
        label.w = 0;
      }
      label.el.classList.toggle("mine", mine);
      label.priority = mine ? 0 : 1;
      this.labelsDirty = true;
    }
    this.renders += 1;
    this.container.dataset.drawn = String(this.renders);
    if (performance.now() - this.lastDeclutter > DECLUTTER_MS) this.declutter();
  }

  droneLayers(name) {
    const arrow =
      '<svg viewBox="-12 -12 24 24" width="24" height="24" aria-hidden="true">' +
      '<path d="M12 0 L-7 7 L-3 0 L-7 -7 Z"/></svg>';
    const body = L.marker(this.frame.latLng(0, 0), {
      pane: "drones",
      icon: icon("map-drone", arrow, 24),
      interactive: false,
      keyboard: false,
    }).addTo(this.map);
    body.getElement().dataset.drone = name;
    const trail = L.polyline([], {
      pane: "trails",
      className: "map-trail",
      weight: 2,
      interactive: false,
    }).addTo(this.map);
    const label = this.addLabel(this.map, this.frame.latLng(0, 0), name, 1, "drone");
    label.el.dataset.drone = name;
    return { body, trail, label };
  }

  /**
   * Place the labels so that none covers another: by priority, each at the first free spot
   * beside its point (SPOTS), else hidden. Sizes are measured once per text.
   */
  declutter() {
    this.labelsDirty = false;
    this.lastDeclutter = performance.now();
    if (!this.map) return;
    const size = this.map.getSize();
    // The zoom buttons, Fit, the scale and the attribution are taken already.
    const origin = this.container.getBoundingClientRect();
    const placed = [...this.container.querySelectorAll(".leaflet-control")].map((c) => {
      const r = c.getBoundingClientRect();
      return { l: r.left - origin.left, t: r.top - origin.top, r: r.right - origin.left, b: r.bottom - origin.top };
    });
    // Nor the drones and the markers themselves.
    const around = (ll, half) => {
      const p = this.map.latLngToContainerPoint(ll);
      return { l: p.x - half, t: p.y - half, r: p.x + half, b: p.y + half };
    };
    for (const d of this.drones.values()) {
      if (d.layers && d.x !== null) placed.push(around(d.layers.body.getLatLng(), ICON_HALF_PX.drone));
    }
    for (const m of this.world?.markers || []) {
      placed.push(around(this.frame.latLng(m.position.x, m.position.y), ICON_HALF_PX.marker));
    }
    const order = [...this.labels].sort((a, b) => a.priority - b.priority);
    for (const label of order) {
      const el = label.el;
      if (!label.marker._map) continue;
      if (!label.w) {
        el.style.transform = "none";
        el.hidden = false;
        label.w = el.offsetWidth;
        label.h = el.offsetHeight;
      }
      const pt = this.map.latLngToContainerPoint(label.marker.getLatLng());
      let spot = null;
      for (const [dx, dy, align] of SPOTS) {
        const left = align === "left" ? pt.x + dx - label.w : align === "center" ? pt.x - label.w / 2 : pt.x + dx;
        const box = { l: left, t: pt.y + dy, r: left + label.w, b: pt.y + dy + label.h };
        if (box.l < 0 || box.r > size.x || box.t < 0 || box.b > size.y) continue; // not all on the map
        if (placed.some((p) => overlaps(p, box))) continue;
        spot = box;
        break;
      }
      if (spot === null) {
        el.hidden = true;
        el.dataset.placed = "0";
        continue;
      }
      placed.push(spot);
      el.hidden = false;
      el.dataset.placed = "1";
      el.style.transform = `translate(${Math.round(spot.l - pt.x)}px, ${Math.round(spot.t - pt.y)}px)`;
    }
  }

  // ---- interaction ---------------------------------------------------------------------------

  onClick(ev) {
    if (!this.world) return;
    const cp = ev.containerPoint;
    let best = null;
    let bestD = HIT_PX;
    for (const m of this.world.markers || []) {
      const p = this.markerPixel(m.id);
      const d = Math.hypot(p.x - cp.x, p.y - cp.y);
      if (d <= bestD) {
        best = m;
        bestD = d;
      }
    }
    if (!best) {
      this.hidePopover();
      return;
    }
    this.showPopover(best.id, cp.x, cp.y);
  }

  /** Offer "go there" for a marker (also used by tests and keyboard users via the console). */
  showPopover(id, cx, cy) {
    this.popoverMarker = id;
    const pop = this.els.popover;
    this.els.text.textContent = `Marker ${id}`;
    this.els.go.textContent = `Go to marker ${id}`;
    pop.hidden = false;
    this.popoverAt = { cx, cy };
    this.placePopover();
    this.els.go.focus();
    this.dirty = true;
  }

  placePopover() {
    const pop = this.els.popover;
    if (pop.hidden || this.popoverMarker === null) return;
    const p = this.markerPixel(this.popoverMarker) || this.popoverAt || { x: 0, y: 0 };
    const rect = this.container.getBoundingClientRect();
    pop.style.visibility = "";
    pop.style.left = `${Math.min(Math.max(4, p.x + 8), rect.width - pop.offsetWidth - 4)}px`;
    pop.style.top = `${Math.min(Math.max(4, p.y + 8), rect.height - pop.offsetHeight - 4)}px`;
  }

  hidePopoverPosition() {
    if (!this.els.popover.hidden) this.els.popover.style.visibility = "hidden";
  }

  onKey(ev) {
    if (ev.target !== this.container) return; // keys in the zoom buttons or the popover
    if (["+", "="].includes(ev.key) || ["-", "_"].includes(ev.key)) {
      ev.preventDefault();
      ev.stopPropagation();
      this.viewTouched = true;
      if (ev.key === "+" || ev.key === "=") this.map?.zoomIn();
      else this.map?.zoomOut();
      return;
    }
    if (ev.key === "f" || ev.key === "F") {
      ev.preventDefault();
      ev.stopPropagation();
      this.fitInterest(true);
      return;
    }
    const markers = [...(this.world?.markers || [])].sort((a, b) => a.id - b.id);
    if (!markers.length) return;
    if (["ArrowRight", "ArrowDown", "ArrowLeft", "ArrowUp", "Home", "End"].includes(ev.key)) {
      ev.preventDefault();
      ev.stopPropagation(); // arrows here pick markers; they never jog the drone
      const n = markers.length;
      if (ev.key === "Home") this.keyIndex = 0;
      else if (ev.key === "End") this.keyIndex = n - 1;
      else {
        const step = ev.key === "ArrowRight" || ev.key === "ArrowDown" ? 1 : -1;
        this.keyIndex = this.keyIndex < 0 ? (step > 0 ? 0 : n - 1) : (this.keyIndex + step + n) % n;
      }
      const m = markers[this.keyIndex];
      this.popoverMarker = m.id;
      if (this.els.focus) this.els.focus.textContent = `Marker ${m.id} of ${n}. Enter offers to fly there.`;
      this.map?.panInside(this.frame.latLng(m.position.x, m.position.y), { padding: [30, 30] });
      this.dirty = true;
    } else if ((ev.key === "Enter" || ev.key === " ") && this.popoverMarker !== null) {
      ev.preventDefault();
      ev.stopPropagation();
      const p = this.markerPixel(this.popoverMarker);
      if (p) this.showPopover(this.popoverMarker, p.x, p.y);
    }
  }

  hidePopover() {
    this.popoverMarker = null;
    this.els.popover.hidden = true;
    this.dirty = true;
  }

  /** Container pixel position of marker ``id`` (for tests and the popover). */
  markerPixel(id) {
    const m = (this.world?.markers || []).find((k) => k.id === id);
    if (!m || !this.map) return null;
    const p = this.map.latLngToContainerPoint(this.frame.latLng(m.position.x, m.position.y));
    return { x: p.x, y: p.y };
  }

  /** Container pixel position of map point (x, y) in metres (tests). */
  pixelOf(x, y) {
    const p = this.map.latLngToContainerPoint(this.frame.latLng(x, y));
    return { x: p.x, y: p.y };
  }
}

function icon(className, html, size) {
  return L.divIcon({ className, html, iconSize: [size, size], iconAnchor: [size / 2, size / 2] });
}

function overlaps(a, b) {
  return a.l < b.r && b.l < a.r && a.t < b.b && b.t < a.b;
}

function escapeHtml(s) {
  return String(s).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);
}

/** A trail as polylines (a null in it breaks the line: a re-localisation, not a flight). */
function trailLines(trail, frame) {
  const lines = [];
  let line = [];
  for (const pt of trail) {
    if (pt === null) {
      if (line.length > 1) lines.push(line);
      line = [];
      continue;
    }
    line.push(frame.latLng(pt[0], pt[1]));
  }
  if (line.length > 1) lines.push(line);
  return lines;
}

// A step longer than this between two estimates is a re-localisation, not a flight: break the line.
const TRAIL_JUMP_M = 1.0;

function pushTrail(d, x, y) {
  let last = null;
  for (let i = d.trail.length - 1; i >= 0 && last === null; i -= 1) last = d.trail[i];
  if (last && Math.hypot(last[0] - x, last[1] - y) <= 0.03) return;
  if (last && Math.hypot(last[0] - x, last[1] - y) > TRAIL_JUMP_M) d.trail.push(null);
  d.trail.push([x, y]);
  while (d.trail.length > TRAIL_LEN) d.trail.shift();
}

function fmtM(v) {
  return Number.isFinite(v) ? String(Math.round(v * 10) / 10) : "?";
}
