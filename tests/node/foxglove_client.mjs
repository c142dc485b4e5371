// Does what Foxglove does with uav-console, with Foxglove's own npm libraries.
//
//   node foxglove_client.mjs live ws://HOST:PORT/rosbridge?token=T SECONDS [TOPIC_REGEX]
//     Foxglove's Rosbridge connection (RosbridgePlayer): @foxglove/roslibjs calls
//     rosapi/topics_and_raw_types, tells ROS 1 from ROS 2 by the type of /rosout, parses every
//     definition with @foxglove/rosmsg, subscribes to every topic (or those TOPIC_REGEX matches,
//     as a Foxglove panel would) with compression "cbor-raw" and reads msg.bytes with
//     @foxglove/rosmsg-serialization's MessageReader.
//   node foxglove_client.mjs mcap FILE.mcap
//     Foxglove's MCAP reader: @mcap/core McapIndexedReader (zstd via fzstd), every message of
//     every channel decoded by its schema (ros1msg -> MessageReader, jsonschema -> JSON).
//
// Prints one JSON object on stdout; the Python test (tests/recorder/test_foxglove.py) judges it.
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";

import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { parse } from "@foxglove/rosmsg";
import { MessageReader } from "@foxglove/rosmsg-serialization";
import { decompress } from "fzstd";

import { WebSocket } from "ws";

// @foxglove/roslibjs is the browser build Foxglove bundles: it uses the global WebSocket
// (Node 20 has none; `ws` is the same API).
globalThis.WebSocket ??= WebSocket;
const require = createRequire(import.meta.url);
const roslib = require("@foxglove/roslibjs");

// Typed arrays and bigints as plain JSON (sizes only for big byte arrays).
function plain(value) {
  if (typeof value === "bigint") return Number(value);
  if (value instanceof Uint8Array) return { bytes: value.length, head: Array.from(value.slice(0, 4)) };
  if (ArrayBuffer.isView(value)) return Array.from(value);
  if (Array.isArray(value)) return value.map(plain);
  if (value && typeof value === "object") {
    return Object.fromEntries(Object.entries(value).map(([k, v]) => [k, plain(v)]));
  }
  return value;
}

async function live(url, seconds, only = null) {
  const ros = new roslib.Ros({ url });
  await new Promise((resolve, reject) => {
    ros.on("connection", resolve);
    ros.on("error", (e) => reject(new Error(`connect failed: ${e?.message ?? e}`)));
  });
  const result = await new Promise((resolve, reject) => {
    ros.getTopicsAndRawTypes(resolve, (e) => reject(new Error(String(e))));
  });
  const { topics, types, typedefs_full_text: defs } = result;
  // RosbridgePlayer: ROS 2 when /rosout carries rcl_interfaces/msg/Log, ROS 1 otherwise.
  const rosoutType = types[topics.indexOf("/rosout")];
  const isRos2 = rosoutType === "rcl_interfaces/msg/Log";
  const out = { rosVersion: isRos2 ? 2 : 1, rosoutType, topics: {} };
  for (let i = 0; i < topics.length; i++) {
    const name = topics[i];
    const entry = (out.topics[name] = { type: types[i], count: 0 });
    let reader;
    try {
      reader = new MessageReader(parse(defs[i], { ros2: isRos2 }));
      entry.parsed = true;
    } catch (e) {
      entry.parsed = false;
      entry.error = `definition: ${e?.message ?? e}`;
      continue;
    }
    if (only && !only.test(name)) continue;
    const topic = new roslib.Topic({ ros, name, messageType: types[i], compression: "cbor-raw" });
    topic.subscribe((message) => {
      try {
        const bytes = new Uint8Array(message.bytes);
        const decoded = reader.readMessage(bytes);
        entry.count += 1;
        if (entry.count === 1) {
          entry.sample = plain(decoded);
          entry.receiveTime = { secs: message.secs, nsecs: message.nsecs };
        }
      } catch (e) {
        entry.error = `decode: ${e?.message ?? e}`;
      }
    });
  }
  process.stderr.write("subscribed\n"); // the test acts (e.g. asks something) from here on
  await new Promise((r) => setTimeout(r, seconds * 1000));
  ros.close();
  return out;
}

async function mcap(file) {
  const data = new Uint8Array(await readFile(file));
  const readable = {
    size: async () => BigInt(data.length),
    read: async (offset, size) => data.subarray(Number(offset), Number(offset + size)),
  };
  const decompressHandlers = { zstd: (buf, size) => decompress(buf, new Uint8Array(Number(size))) };
  const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
  const decoders = new Map();
  const out = { profile: reader.header.profile, library: reader.header.library, topics: {}, errors: [] };
  for (const [id, channel] of reader.channelsById) {
    const schema = reader.schemasById.get(channel.schemaId);
    const text = new TextDecoder().decode(schema.data);
    out.topics[channel.topic] = {
      type: schema.name,
      schemaEncoding: schema.encoding,
      messageEncoding: channel.messageEncoding,
      count: 0,
    };
    if (schema.encoding === "ros1msg" && channel.messageEncoding === "ros1") {
      const r = new MessageReader(parse(text, { ros2: false }));
      decoders.set(id, (bytes) => r.readMessage(bytes));
    } else if (schema.encoding === "jsonschema" && channel.messageEncoding === "json") {
      JSON.parse(text);
      decoders.set(id, (bytes) => JSON.parse(new TextDecoder().decode(bytes)));
    } else {
      out.errors.push(`${channel.topic}: no decoder for ${schema.encoding}/${channel.messageEncoding}`);
    }
  }
  let total = 0;
  for await (const msg of reader.readMessages({ validateCrcs: true })) {
    const channel = reader.channelsById.get(msg.channelId);
    const entry = out.topics[channel.topic];
    try {
      const decoded = decoders.get(msg.channelId)(msg.data);
      entry.count += 1;
      if (entry.count === 1) entry.sample = plain(decoded);
    } catch (e) {
      out.errors.push(`${channel.topic}: ${e?.message ?? e}`);
    }
    total += 1;
  }
  out.messages = total;
  out.statistics = reader.statistics ? Number(reader.statistics.messageCount) : null;
  out.metadata = {};
  for await (const m of reader.readMetadata()) out.metadata[m.name] = Object.fromEntries(m.metadata);
  // The streaming reader (Foxglove's for non-seekable sources) must read it whole too.
  const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  stream.append(data);
  let streamed = 0;
  for (let rec; (rec = stream.nextRecord()); ) if (rec.type === "Message") streamed += 1;
  out.streamed = streamed;
  out.streamDone = stream.done();
  return out;
}

const [mode, arg, extra, pattern] = process.argv.slice(2);
try {
  const only = pattern ? new RegExp(pattern) : null;
  const out = mode === "live" ? await live(arg, Number(extra ?? 3), only) : await mcap(arg);
  process.stdout.write(JSON.stringify(out));
  process.exit(0);
} catch (e) {
  process.stdout.write(JSON.stringify({ fatal: String(e?.stack ?? e) }));
  process.exit(1);
}
