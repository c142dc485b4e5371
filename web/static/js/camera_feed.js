// The selected drone's camera subscription, throttled to what this page can show.
//
// rosbridge pushes every frame (15 fps, ~50 KB of base64 each). A page that shows fewer (a busy
// phone, a loaded machine, several drones' stacks on one host) does not drop the rest: they
// wait in the server's send queue, the kernel's socket buffers and the browser's message
// queue, and the picture falls seconds behind the drone (3.3 s at 4 fps was measured with two
// drones). So the page watches how late frames arrive and asks the server for fewer when they
// queue: the subscription's ``throttle_rate`` (rosbridge protocol §3.4.6; with ``queue_length``
// 1 the server keeps only the newest frame of each window) steps up until the backlog is gone
// and back down when frames arrive on time again. Lateness is the server's stamp against the
// server's clock as the page knows it (app.js syncClock: exact on one machine, within half a
// round trip across the network).

/** throttle_rate steps (ms between frames): all frames, 10, 5, 2.5 fps. */
export const STEPS_MS = [0, 100, 200, 400];
export const QUEUED_MS = 400; // frames this late (median over a second) are queueing
export const ON_TIME_MS = 150; // ... and this late, on time
const WINDOW_MS = 1000; // lateness judged over the last second of frames
const STEP_UP_MS = 1000; // at least this long between two steps up
const STEP_DOWN_MS = 1500; // and this long on time before a step down

export class CameraFeed {
  /**
   * @param {{subscribe: Function}} ros the rosbridge client
   * @param {{onImage: (msg: object) => void}} camera the camera panel
   * @param {() => number} serverNow the server's clock (Unix seconds) as the page knows it
   * @param {() => number} clock the page's monotonic clock (ms)
   */
  constructor(ros, camera, serverNow, clock = () => performance.now()) {
    this.ros = ros;
    this.camera = camera;
    this.serverNow = serverNow;
    this.clock = clock;
    this.topic = null;
    this.type = null;
    this.sub = null;
    this.level = 0;
    this.samples = []; // [page ms, lateness ms]
    this.changedAt = 0;
  }

  /** Follow ``topic`` (a drone's /ardrone/image_raw/compressed), all frames to begin with. */
  attach(topic, type) {
    this.detach();
    this.topic = topic;
    this.type = type;
    this.level = 0;
    this.samples = [];
    this.changedAt = this.clock();
    this.subscribe();
    return { unsubscribe: () => this.detach() };
  }

  detach() {
    this.sub?.unsubscribe();
    this.sub = null;
  }

  get throttleMs() {
    return STEPS_MS[this.level];
  }

  subscribe() {
    this.sub?.unsubscribe();
    this.sub = this.ros.subscribe(this.topic, this.type, (m) => this.onImage(m), {
      queue_length: 1,
      throttle_rate: STEPS_MS[this.level],
    });
  }

  onImage(msg) {
    const s = msg?.header?.stamp;
    const sec = s?.sec ?? s?.secs;
    if (typeof sec === "number" && sec > 0) {
      const late = (this.serverNow() - (sec + (s.nanosec ?? s.nsecs ?? 0) / 1e9)) * 1000;
      this.adapt(this.clock(), late);
    }
    this.camera.onImage(msg);
  }

  /** One frame's lateness (ms) at page time ``now`` (ms): step the throttle if due. */
  adapt(now, late) {
    const samples = this.samples;
    samples.push([now, late]);
    while (samples.length && now - samples[0][0] > WINDOW_MS) samples.shift();
    if (samples.length < 3) return;
    const recent = samples.map((x) => x[1]);
    recent.sort((a, b) => a - b);
    const excess = recent[Math.floor(recent.length / 2)];
    const since = now - this.changedAt;
    if (excess > QUEUED_MS && since > STEP_UP_MS && this.level < STEPS_MS.length - 1) {
      this.level += 1;
    } else if (excess < ON_TIME_MS && since > STEP_DOWN_MS && this.level > 0) {
      this.level -= 1;
    } else {
      return;
    }
    this.changedAt = now;
    this.subscribe();
  }
}
