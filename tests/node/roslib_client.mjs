// Drives roslibjs (npm `roslib`, unchanged) against a uav-console rosbridge endpoint.
// Usage: node roslib_client.mjs ws://127.0.0.1:PORT/rosbridge?token=T
// Runs every scenario in turn and prints one JSON object {scenario: result} on stdout.
// tests/rosbridge/test_roslibjs.py checks the results; this script only reports what it saw.
import { Ros, Topic, Service, Param } from "roslib";

const url = process.argv[2];
const results = {};

function connect() {
  return new Promise((resolve, reject) => {
    const ros = new Ros({ url });
    ros.on("connection", () => resolve(ros));
    ros.on("error", (e) => reject(new Error(`connect failed: ${e?.message ?? e}`)));
  });
}

function within(ms, what, fn) {
  return new Promise((resolve, reject) => {
    const timer = setTimeout(() => reject(new Error(`timeout: ${what}`)), ms);
    fn((v) => { clearTimeout(timer); resolve(v); }, (e) => { clearTimeout(timer); reject(e); });
  });
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

async function scenario(name, fn) {
  try {
    results[name] = await fn();
  } catch (e) {
    results[name] = { error: String(e?.message ?? e) };
  }
}

const a = await connect();
const b = await connect();

await scenario("pubsub", async () => {
  const sub = new Topic({ ros: b, name: "/js/chatter", messageType: "std_msgs/String" });
  const pub = new Topic({ ros: a, name: "/js/chatter", messageType: "std_msgs/String" });
  const got = within(5000, "pubsub", (ok) => sub.subscribe((m) => ok(m)));
  for (let i = 0; i < 50; i++) { pub.publish({ data: `hello ${i}` }); await sleep(20); if (results.pubsub) break; }
  const m = await got;
  sub.unsubscribe();
  return m;
});

await scenario("from_graph", async () => {
  // the Python side publishes /py/ticker (std_msgs/Int32) every 20 ms
  const sub = new Topic({ ros: b, name: "py/ticker", messageType: "std_msgs/Int32" });
  const m = await within(5000, "from_graph", (ok) => sub.subscribe((x) => ok(x)));
  sub.unsubscribe();
  return m;
});

await scenario("latched", async () => {
  const pub = new Topic({ ros: a, name: "/js/latched", messageType: "std_msgs/String", latch: true });
  pub.publish({ data: "kept" });
  await sleep(200);
  const c = await connect();
  const sub = new Topic({ ros: c, name: "/js/latched", messageType: "std_msgs/String" });
  const m = await within(5000, "latched", (ok) => sub.subscribe((x) => ok(x)));
  c.close();
  return m;
});

await scenario("client_service", async () => {
  const server = new Service({ ros: a, name: "/js/add", serviceType: "example/AddTwoInts" });
  await server.advertise((req, res) => { res.sum = req.a + req.b; return true; });
  await sleep(200);
  const client = new Service({ ros: b, name: "/js/add", serviceType: "example/AddTwoInts" });
  return await within(5000, "client_service", (ok, bad) => client.callService({ a: 20, b: 22 }, ok, bad));
});

await scenario("graph_service", async () => {
  const client = new Service({ ros: b, name: "/py/echo", serviceType: "example/Echo" });
  return await within(5000, "graph_service", (ok, bad) => client.callService({ text: "ping" }, ok, bad));
});

await scenario("service_failure", async () => {
  const client = new Service({ ros: b, name: "/does/not/exist", serviceType: "example/Echo" });
  return await within(5000, "service_failure", (ok, bad) =>
    client.callService({}, (v) => bad(new Error(`unexpected success ${JSON.stringify(v)}`)), (err) => ok({ failed: err })));
});

await scenario("params", async () => {
  const p = new Param({ ros: a, name: "js_param" });
  await within(5000, "set", (ok, bad) => p.set({ k: [1, 2, 3] }, ok, bad));
  const got = await within(5000, "get", (ok, bad) => p.get(ok, bad));
  await within(5000, "delete", (ok, bad) => p.delete(ok, bad));
  const names = await within(5000, "names", (ok, bad) => a.getParams(ok, bad));
  return { got, names };
});

await scenario("topics", async () => {
  return await within(5000, "getTopics", (ok, bad) => a.getTopics(ok, bad));
});

await scenario("message_details", async () => {
  const defs = await within(5000, "details", (ok, bad) => a.getMessageDetails("geometry_msgs/Twist", ok, bad));
  return a.decodeTypeDefs(defs);
});

await scenario("throttle", async () => {
  // throttle_rate 1000 ms, queue_length 0: of a quick burst only the first gets through.
  const sub = new Topic({ ros: b, name: "/js/fast", messageType: "std_msgs/Int32", throttle_rate: 1000 });
  const seen = [];
  sub.subscribe((m) => seen.push(m.data));
  await sleep(300);
  const pub = new Topic({ ros: a, name: "/js/fast", messageType: "std_msgs/Int32" });
  for (let i = 1; i <= 10; i++) pub.publish({ data: i });
  await sleep(500);
  sub.unsubscribe();
  return seen;
});

await scenario("queue", async () => {
  // throttle_rate 300 ms, queue_length 2: first at once, then the newest two, one per window.
  const sub = new Topic({ ros: b, name: "/js/queued", messageType: "std_msgs/Int32", throttle_rate: 300, queue_length: 2 });
  const seen = [];
  sub.subscribe((m) => seen.push(m.data));
  await sleep(300);
  const pub = new Topic({ ros: a, name: "/js/queued", messageType: "std_msgs/Int32" });
  for (let i = 1; i <= 10; i++) pub.publish({ data: i });
  await sleep(1200);
  sub.unsubscribe();
  return seen;
});

await scenario("fragments", async () => {
  // a raw subscribe with fragment_size (the server's minimum, 1024): the server splits,
  // roslibjs reassembles.
  const got = within(5000, "fragments", (ok) => b.on("/js/big", (m) => ok(m.msg)));
  b.callOnConnection({ op: "subscribe", id: "subscribe:/js/big:frag", topic: "/js/big", type: "std_msgs/String", fragment_size: 1024 });
  await sleep(300);
  // and the client sends a publish in fragments too
  const text = JSON.stringify({ op: "publish", topic: "/js/big", msg: { data: "x".repeat(3000) + "END" } });
  const n = Math.ceil(text.length / 300);
  a.callOnConnection({ op: "advertise", topic: "/js/big", type: "std_msgs/String" });
  for (let i = 0; i < n; i++) {
    a.callOnConnection({ op: "fragment", id: "frag-up-1", data: text.slice(i * 300, (i + 1) * 300), num: i, total: n });
  }
  return await got;
});

await scenario("png", async () => {
  const sub = new Topic({ ros: b, name: "/js/png", messageType: "std_msgs/String", compression: "png" });
  const got = within(5000, "png", (ok) => sub.subscribe((m) => ok(m)));
  await sleep(300);
  new Topic({ ros: a, name: "/js/png", messageType: "std_msgs/String" }).publish({ data: "through a png" });
  const m = await got;
  sub.unsubscribe();
  return m;
});

await scenario("cbor", async () => {
  const sub = new Topic({ ros: b, name: "/js/image", messageType: "sensor_msgs/CompressedImage", compression: "cbor" });
  const got = within(5000, "cbor", (ok) => sub.subscribe((m) => ok(m)));
  await sleep(300);
  const nav = new Topic({ ros: b, name: "/js/navdata", messageType: "ardrone_autonomy/Navdata", compression: "cbor" });
  const gotNav = within(5000, "cbor navdata", (ok) => nav.subscribe((m) => ok(m)));
  await sleep(300);
  new Topic({ ros: a, name: "/js/image", messageType: "sensor_msgs/CompressedImage" })
    .publish({ format: "jpeg", data: Buffer.from([255, 216, 1, 2, 3, 255, 217]).toString("base64") });
  new Topic({ ros: a, name: "/js/navdata", messageType: "ardrone_autonomy/Navdata" })
    .publish({ batteryPercent: 87.5, tags_xc: [10, 20, 300000], tags_distance: [1.5, 2.25] });
  const m = await got;
  const n = await gotNav;
  return {
    format: m.format,
    dataIsBytes: m.data instanceof Uint8Array,
    data: Array.from(m.data),
    stampSec: typeof m.header.stamp.sec,
    battery: n.batteryPercent,
    tagsXcType: n.tags_xc?.constructor?.name,
    tagsXc: Array.from(n.tags_xc),
    tagsDistanceType: n.tags_distance?.constructor?.name,
    tagsDistance: Array.from(n.tags_distance),
  };
});

await scenario("status", async () => {
  // a frame the server rejects comes back as a status error with our id
  const got = within(5000, "status", (ok) => b.on("status:bad-1", (s) => ok(s)));
  b.callOnConnection({ op: "publish", id: "bad-1", topic: "/js/chatter", msg: { data: 42 } });
  return await got;
});

a.close();
b.close();
process.stdout.write(JSON.stringify(results) + "\n");
process.exit(0);
