// Age on every value: one rule for the whole page.
//
// Every value on the page comes from a source: the server (its heartbeat on rosbridge), the
// selected drone's vehicle (navdata, or the REST snapshot where a drone has no navdata topic),
// its camera (frames), the fleet status. A source is as old as the last word heard from it, and
// it is stale once it has been silent for longer than staleAfterS(its period): 1 s for a stream
// (the roads' rule, door.js DOOR_DEAD_MS), 2.5 periods for a polled source. A source behind a
// stale upstream (everything is behind the server) is stale with it.
//
// What stale does, the same for every panel that registered the source: the panel gets
// data-stale="true" (console.css greys it), its badge says "3.2 s old", and the source that
// stopped (not the ones behind it) raises an alarm that names it, once it has been silent long
// enough for a stopped upstream to show too (so the alarm names the cause); when it speaks
// again the alarm says so and stays until acknowledged, like every alarm (alerts.js). A source
// never heard from is "waiting", not stale: a drone without a camera raises nothing.
//
// A source the page learns was replaced (a vehicle process that died and was restarted: a new
// pid) raises its alarm even when the new one spoke before the alarm was due, since the
// silence was no hiccup (replaced()); it says at once that the source is back.
//
// A source behind one that comes back or is replaced starts again: a new vehicle process opens
// its camera after its telemetry flows, so the camera's silence until then is the vehicle's, not
// its own. Its panel still greys with its age, but its alarm waits START_GRACE_S for its first
// word (an alarm it raised before the page learnt of the restart is dropped: the vehicle's
// covers it).

export const STALE_MIN_S = 1.0;
export const STALE_PERIODS = 2.5;
export const TICK_MS = 250;
// A tick this late means the page itself was paused (TICK_MS apart when it runs freely).
const PAGE_STALL_S = 0.6;
// How long a source behind a restarted one may take to speak again before its own alarm: a
// vehicle process's first camera frame (decoder opened, first key frame) comes 0.1–3 s after its
// telemetry on a loaded 2-core machine; 10 s keeps a camera that never comes back from hiding.
export const START_GRACE_S = 10;

/** Seconds of silence after which a source with this period is stale (the one rule). */
export function staleAfterS(periodS = 0) {
  const p = Number.isFinite(periodS) && periodS > 0 ? periodS : 0;
  return Math.max(STALE_MIN_S, STALE_PERIODS * p);
}

/** "0.4 s", "12 s", "3 min": an age as the page says it. */
export function ageWords(ageS) {
  if (!Number.isFinite(ageS) || ageS < 0) return "–";
  if (ageS < 10) return `${ageS.toFixed(1)} s`;
  if (ageS < 120) return `${Math.round(ageS)} s`;
  return `${Math.round(ageS / 60)} min`;
}

/** "3.2 s old": the badge of a stale panel. */
export function ageText(ageS) {
  return `${ageWords(ageS)} old`;
}

/**
 * @typedef {object} SourceSpec
 * @property {number} [periodS] how often it speaks when well (0: a stream, 1 s rule)
 * @property {string|null} [upstream] the source it reaches the page through ("server")
 * @property {(age: string, why: string) => string} [alarm] the alarm while it is silent
 * @property {(age: string, why: string) => string} [back] the alarm's text once it speaks
 *   again (why: what the page learnt of the silence meanwhile, "" when nothing)
 * @property {string} [key] the alarm's key (default "fresh:NAME"; a drone's name in it keeps
 *   one drone's alarm apart from the next one's)
 */

export class Freshness {
  /**
   * @param {{now?: () => number,
   *          alarms?: {raise: Function, update: Function, clear: Function}}} opts
   *   now: this page's clock in seconds; alarms: the alert banner (alerts.js AlertBanner)
   */
  constructor({ now = () => performance.now() / 1000, alarms = null } = {}) {
    this.now = now;
    this.alarms = alarms;
    /** name -> {spec, heardAt, why, alarmed, staleSince} */
    this.sources = new Map();
    /** [{el, names, badge, show}] */
    this.panels = [];
    this.suspended = false;
  }

  /** Define (or redefine: a newly selected drone) a source; it starts "waiting". An alarm the
   *  old definition raised stands until acknowledged (it names its drone). */
  source(name, spec = {}) {
    this.sources.set(name, {
      spec: { periodS: 0, upstream: null, ...spec },
      heardAt: null,
      why: "",
      alarmed: false,
      staleSince: null,
      gap: null,
      note: "",
      upStale: false,
      graceUntil: null,
    });
    return this;
  }

  /** Something fresh from ``name``; ``at`` is when it was fresh (default: now). */
  beat(name, at = this.now()) {
    const s = this.sources.get(name);
    if (!s) return;
    if (s.heardAt !== null && at - s.heardAt > staleAfterS(s.spec.periodS)) {
      s.gap = { from: s.heardAt, to: at }; // its last silence, for replaced()
    }
    if (s.heardAt === null || at > s.heardAt) s.heardAt = at;
    s.graceUntil = null;
  }

  /** The sources behind ``name`` start again: their alarms wait START_GRACE_S for a first
   *  word, and one raised already is dropped (the alarm of ``name`` says why they were silent). */
  restartBehind(name, now) {
    for (const [behind, d] of this.sources) {
      if (d.spec.upstream !== name) continue;
      d.graceUntil = now + START_GRACE_S;
      if (d.alarmed && !d.saidBack) {
        d.alarmed = false;
        this.alarms?.drop?.(this.alarmKey(behind));
      }
    }
  }

  /**
   * ``name`` was replaced by a new one (``why`` says how): its alarm is raised now if the rule
   * has not raised it (the new one spoke first) and, once it is fresh, says it is back.
   */
  replaced(name, why, now = this.now()) {
    const s = this.sources.get(name);
    if (!s || this.suspended || !this.alarms || !s.spec.alarm) return;
    this.restartBehind(name, now);
    s.note = why;
    if (s.alarmed) return;
    if (s.saidBack && s.gap && s.gap.from === s.staleSince) {
      // The rule raised it and said it back already: the back line names the restart too.
      this.alarms.clear(this.alarmKey(name), s.spec.back?.(ageWords(s.gap.to - s.gap.from), why));
      s.note = "";
      return;
    }
    const stillSilent = this.ownStale(name, now);
    const from = stillSilent || !s.gap ? s.heardAt : s.gap.from;
    const silentS = stillSilent || !s.gap ? this.age(name, now) : s.gap.to - s.gap.from;
    if (from === null) return;
    s.alarmed = true;
    s.saidBack = false;
    s.staleSince = from;
    this.alarms.raise(this.alarmKey(name), s.spec.alarm(ageWords(silentS), why));
    if (!stillSilent) this.judge(name, s, now); // the new one already spoke: back, at once
  }

  /** How often ``name`` speaks when well (a drone whose navdata flows, or REST only). */
  setPeriod(name, periodS) {
    const s = this.sources.get(name);
    if (s) s.spec.periodS = periodS;
  }

  /** What the page knows of why ``name`` is silent ("its vehicle process does not answer"). */
  setWhy(name, why) {
    const s = this.sources.get(name);
    if (s) s.why = why || "";
  }

  /** Seconds since ``name`` was last fresh (null: never heard). */
  age(name, now = this.now()) {
    const s = this.sources.get(name);
    return s && s.heardAt !== null ? Math.max(0, now - s.heardAt) : null;
  }

  /** Silent for longer than its rule allows (a source never heard is not stale). */
  ownStale(name, now = this.now()) {
    const s = this.sources.get(name);
    const age = this.age(name, now);
    return Boolean(s) && age !== null && age > staleAfterS(s.spec.periodS);
  }

  /** Stale itself or behind a stale upstream; with the age to show (null when fresh). */
  staleAge(name, now = this.now()) {
    const s = this.sources.get(name);
    if (!s) return null;
    const up = s.spec.upstream ? this.staleAge(s.spec.upstream, now) : null;
    if (this.ownStale(name, now)) return Math.max(this.age(name, now), up ?? 0);
    return up;
  }

  /**
   * A panel fed by ``names``: greyed with its age while any of them is stale.
   * @param {HTMLElement} el
   * @param {string[]} names
   * @param {{badge?: HTMLElement|null, show?: (age: number|null) => void}} [opts]
   *   badge: where "n s old" is written (default: a badge made in the panel's corner;
   *   null: none); show: a panel's own way of saying it instead
   */
  panel(el, names, { badge, show } = {}) {
    if (!el) return this;
    let b = badge;
    if (b === undefined && !show) {
      b = document.createElement("span");
      b.className = "age-badge";
      b.hidden = true;
      el.append(b);
    }
    this.panels.push({ el, names, badge: b ?? null, show: show ?? null });
    return this;
  }

  /** A replay plays recorded time: ages are not the present's, nothing is stale. */
  suspend(on) {
    this.suspended = Boolean(on);
  }

  alarmKey(name) {
    return this.sources.get(name)?.spec.key ?? `fresh:${name}`;
  }

  /** Apply the rule now: panels, badges and alarms. After a pause of the page itself (its
   *  thread busy, a background tab's throttled timers) the messages that waited meanwhile are
   *  read first: that tick judges nothing, so the page's stall is never blamed on a source. */
  tick(now = this.now()) {
    const gap = this.lastTick === undefined ? 0 : now - this.lastTick;
    this.lastTick = now;
    if (gap > PAGE_STALL_S && !this.skipped) {
      this.skipped = true;
      return;
    }
    this.skipped = false;
    for (const p of this.panels) {
      let age = null;
      if (!this.suspended) {
        for (const n of p.names) {
          const a = this.staleAge(n, now);
          if (a !== null) age = Math.max(age ?? 0, a);
        }
      }
      const stale = age !== null;
      if (p.el.dataset.stale !== String(stale)) p.el.dataset.stale = String(stale);
      if (p.show) p.show(age);
      if (p.badge) {
        const text = stale ? ageText(age) : "";
        if (p.badge.textContent !== text) p.badge.textContent = text;
        p.badge.hidden = !stale;
      }
    }
    for (const [name, s] of this.sources) this.judge(name, s, now);
  }

  /** Whether ``name`` has been silent long enough that a stale upstream would show by now: a
   *  camera's last frame may precede its vehicle's last navdata by a few tens of ms, and the
   *  alarm must name the vehicle then, not the camera. */
  causeKnown(name, now) {
    const s = this.sources.get(name);
    const up = s.spec.upstream ? this.sources.get(s.spec.upstream) : null;
    const wait = staleAfterS(s.spec.periodS) + (up ? staleAfterS(up.spec.periodS) : 0);
    return this.age(name, now) > wait;
  }

  judge(name, s, now) {
    if (!this.alarms) return;
    const key = this.alarmKey(name);
    const own = !this.suspended && this.ownStale(name, now);
    const upstream = s.spec.upstream ? this.staleAge(s.spec.upstream, now) !== null : false;
    if (s.upStale && !upstream && !this.suspended) this.restartBehind(s.spec.upstream, now);
    s.upStale = upstream;
    const starting = s.graceUntil !== null && now < s.graceUntil;
    const age = ageWords(this.age(name, now));
    if (own && !s.alarmed && !upstream && !starting && s.spec.alarm && this.causeKnown(name, now)) {
      s.alarmed = true;
      s.saidBack = false;
      s.staleSince = s.heardAt;
      this.alarms.raise(key, s.spec.alarm(age, s.why));
    } else if (own && s.alarmed && s.spec.alarm) {
      this.alarms.update(key, s.spec.alarm(age, s.why)); // only while not yet acknowledged
    } else if (!own && s.alarmed) {
      s.alarmed = false;
      // Silent from its last word before the alarm to the first word after it.
      const first = s.gap && s.gap.from === s.staleSince ? s.gap.to : s.heardAt;
      const silent = s.staleSince !== null && first !== null ? first - s.staleSince : null;
      const back = s.spec.back ? s.spec.back(ageWords(silent), s.note) : "";
      s.note = "";
      s.saidBack = true;
      if (this.suspended) this.alarms.drop?.(key);
      else this.alarms.clear(key, back);
    }
  }
}
