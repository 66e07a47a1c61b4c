// The reference client of the Foxglove WebSocket protocol, for tests/it/view.rs:
// `@foxglove/ws-protocol`'s FoxgloveClient (what Lichtblick and older Foxglove
// Studio connect with) over the `ws` package, offering only the subprotocol it
// names, foxglove.websocket.v1. It subscribes to every channel the server
// advertises and decodes each message with the schema the server advertised:
// protobuf through protobufjs from the advertised FileDescriptorSet (as Lichtblick
// does), JSON as JSON. Nothing here knows isochron's channels.
//
// The packages come from target/node-peers (tests/view/package.json, installed by
// `cargo xtask setup`); run with NODE_PATH=target/node-peers/node_modules.
//
// usage: node foxglove_client.cjs URL TIMEOUT_S [SETTLE_S]
// Ends once every advertised channel has given a decoded message and nothing new
// was advertised for SETTLE_S (default 6), or at TIMEOUT_S. Prints one JSON object:
// the agreed subprotocol, the server's name, per topic the advertised schema, the
// messages received and decoded and a summary of the first, the errors, and the
// topics that gave nothing (`missing`). Exits 0 when it printed, whatever it found.

"use strict";

const { FoxgloveClient } = require("@foxglove/ws-protocol");
const protobuf = require("protobufjs");
const { FileDescriptorSet } = require("protobufjs/ext/descriptor");
const WebSocket = require("ws");

const [url, timeoutArg, settleArg] = process.argv.slice(2);
const timeoutMs = Number(timeoutArg) * 1000;
const settleMs = Number(settleArg ?? "6") * 1000;

const out = {
  subprotocol: null,
  opened: false,
  server: null,
  channels: {},
  errors: [],
  missing: [],
  closed: null,
};
/** Per subscription id: the channel's topic and its decoder. */
const subscriptions = new Map();
let lastAdvertise = Date.now();

/** A function that decodes a message of `channel`, from what the server advertised. */
function decoderFor(channel) {
  if (channel.encoding === "protobuf" && channel.schemaEncoding === "protobuf") {
    // Binary schemas are base64 in the advertisement (the protocol's spec).
    const descriptors = FileDescriptorSet.decode(Buffer.from(channel.schema, "base64"));
    const root = protobuf.Root.fromDescriptor(descriptors);
    root.resolveAll();
    const type = root.lookupType(channel.schemaName);
    return (bytes) =>
      type.toObject(type.decode(bytes), { longs: Number, bytes: Buffer, defaults: true });
  }
  if (channel.encoding === "json") {
    return (bytes) => JSON.parse(Buffer.from(bytes).toString("utf8"));
  }
  throw new Error(
    `no decoder for message encoding '${channel.encoding}', schema encoding '${channel.schemaEncoding}'`,
  );
}

/** Checks a decoded message of the well-known schema `name`; a summary of it. */
function summarize(name, m) {
  const need = (ok, what) => {
    if (!ok) {
      throw new Error(`${name}: ${what}`);
    }
  };
  switch (name) {
    case "foxglove.Grid": {
      const fields = m.fields.map((f) => f.name);
      need(m.cell_stride > 0 && m.column_count > 0, "no cells");
      need(m.row_stride >= m.column_count * m.cell_stride, "row_stride shorter than a row");
      need(m.data.length % m.row_stride === 0, "data not whole rows");
      need(fields.length > 0, "no fields");
      return {
        frame_id: m.frame_id,
        columns: m.column_count,
        rows: m.data.length / m.row_stride,
        cell_stride: m.cell_stride,
        fields,
      };
    }
    case "foxglove.Log":
      need(typeof m.message === "string" && m.message.length > 0, "empty message");
      return { level: m.level, name: m.name, message: m.message.slice(0, 80) };
    case "foxglove.CompressedImage":
      need(m.format === "jpeg", `format '${m.format}'`);
      need(m.data[0] === 0xff && m.data[1] === 0xd8, "not a JPEG");
      return { format: m.format, bytes: m.data.length };
    case "foxglove.SceneUpdate":
      return { entities: m.entities.length, deletions: m.deletions.length };
    case "foxglove.ImageAnnotations":
      return { points: m.points.length, texts: m.texts.length, circles: m.circles.length };
    default:
      return { keys: Object.keys(m).sort() };
  }
}

function finish() {
  out.missing = Object.entries(out.channels)
    .filter(([, c]) => c.decoded === 0)
    .map(([topic]) => topic)
    .sort();
  process.stdout.write(`${JSON.stringify(out)}\n`);
  process.exit(0);
}

const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });

client.on("open", () => {
  out.opened = true;
  out.subprotocol = ws.protocol;
});
client.on("error", (error) => {
  out.errors.push(`client: ${error?.message ?? error}`);
});
client.on("close", (event) => {
  out.closed = { code: event.code, reason: String(event.reason ?? "") };
  finish();
});
client.on("serverInfo", (info) => {
  out.server = info.name;
});
client.on("advertise", (channels) => {
  lastAdvertise = Date.now();
  for (const channel of channels) {
    const entry = {
      id: channel.id,
      encoding: channel.encoding,
      schema: channel.schemaName,
      schema_encoding: channel.schemaEncoding ?? null,
      received: 0,
      decoded: 0,
      first: null,
    };
    out.channels[channel.topic] = entry;
    let decode;
    try {
      decode = decoderFor(channel);
    } catch (error) {
      out.errors.push(`${channel.topic}: schema: ${error.message}`);
      continue;
    }
    const id = client.subscribe(channel.id);
    subscriptions.set(id, { topic: channel.topic, schema: channel.schemaName, decode, entry });
  }
});
client.on("message", ({ subscriptionId, data }) => {
  const sub = subscriptions.get(subscriptionId);
  if (sub === undefined) {
    out.errors.push(`message for unknown subscription ${subscriptionId}`);
    return;
  }
  sub.entry.received += 1;
  try {
    const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    const summary = summarize(sub.schema, sub.decode(bytes));
    sub.entry.decoded += 1;
    sub.entry.first ??= summary;
  } catch (error) {
    if (sub.entry.errors === undefined) {
      sub.entry.errors = 0;
      out.errors.push(`${sub.topic}: decoding: ${error.message}`);
    }
    sub.entry.errors += 1;
  }
});

const started = Date.now();
setInterval(() => {
  const entries = Object.values(out.channels);
  const all = entries.length > 0 && entries.every((c) => c.decoded > 0);
  if ((all && Date.now() - lastAdvertise >= settleMs) || Date.now() - started >= timeoutMs) {
    finish();
  }
}, 200);
