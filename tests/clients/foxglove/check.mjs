// Reads a swarm-explore run the way Foxglove does, with Foxglove's own libraries from npm:
//
//   node check.mjs mcap FILE        # @mcap/core's stream reader, CRCs validated
//   node check.mjs live ws://ADDR   # @foxglove/ws-protocol's FoxgloveClient, every channel subscribed
//
// Every channel's schema is parsed as Foxglove's app parses protobuf channels (protobufjs: the
// FileDescriptorSet the schema holds, then the type the schema names) and every message is
// decoded with it. Prints one JSON line {"topics": {topic: {schema, messages}}, "logTimeRegressions": n}
// and exits 0; any failure exits 1 with the reason on stderr.

import { readFileSync } from "node:fs";
import { McapStreamReader } from "@mcap/core";
import wsProtocol from "@foxglove/ws-protocol";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

/** A decoder of a protobuf channel: parse the descriptor set, look the type up. */
function protobufDecoder(schemaName, schemaBytes) {
  const set = descriptor.FileDescriptorSet.decode(schemaBytes);
  const root = protobuf.Root.fromDescriptor(set);
  root.resolveAll();
  const type = root.lookupType(schemaName);
  return (data) => type.toObject(type.decode(data), { longs: Number, bytes: Buffer });
}

const topics = {};
function channel(topic, schemaName, encoding, schemaEncoding, schemaBytes) {
  if (encoding !== "protobuf" || schemaEncoding !== "protobuf") {
    throw new Error(`${topic}: encoding ${encoding}, schema encoding ${schemaEncoding}`);
  }
  const decode = protobufDecoder(schemaName, schemaBytes);
  topics[topic] = { schema: schemaName, messages: 0 };
  return (data) => {
    decode(data);
    topics[topic].messages += 1;
  };
}

function fail(e) {
  console.error(e?.stack ?? String(e));
  process.exit(1);
}

function mcap(path) {
  const reader = new McapStreamReader({ validateCrcs: true });
  reader.append(new Uint8Array(readFileSync(path)));
  const schemas = new Map();
  const decoders = new Map();
  let last = 0n;
  let regressions = 0;
  for (let r; (r = reader.nextRecord()); ) {
    if (r.type === "Schema") {
      schemas.set(r.id, r);
    } else if (r.type === "Channel" && !decoders.has(r.id)) {
      // (The summary section repeats every channel.)
      const s = schemas.get(r.schemaId);
      if (!s) throw new Error(`${r.topic}: no schema ${r.schemaId}`);
      decoders.set(r.id, channel(r.topic, s.name, r.messageEncoding, s.encoding, s.data));
    } else if (r.type === "Message") {
      if (r.logTime < last) regressions += 1;
      last = r.logTime;
      decoders.get(r.channelId)(r.data);
    }
  }
  if (!reader.done()) throw new Error("the file does not end as an MCAP file ends");
  console.log(JSON.stringify({ topics, logTimeRegressions: regressions }));
}

function live(url) {
  const client = new FoxgloveClient({
    // Foxglove's SDK (0.30) negotiates `foxglove.sdk.v1`, the current name of the protocol this
    // client speaks (`foxglove.websocket.v1`, which it offers by default): the same messages.
    ws: new WebSocket(url, ["foxglove.sdk.v1"]),
  });
  const bySubscription = new Map();
  client.on("error", fail);
  client.on("advertise", (channels) => {
    for (const c of channels) {
      const schema = Buffer.from(c.schema, "base64");
      const decode = channel(c.topic, c.schemaName, c.encoding, c.schemaEncoding, schema);
      bySubscription.set(client.subscribe(c.id), decode);
    }
  });
  client.on("message", (m) => {
    const data = new Uint8Array(m.data.buffer, m.data.byteOffset, m.data.byteLength);
    try {
      bySubscription.get(m.subscriptionId)(data);
    } catch (e) {
      fail(e);
    }
  });
  client.on("close", () => {
    console.log(JSON.stringify({ topics, logTimeRegressions: 0 }));
    process.exit(0);
  });
}

try {
  const [mode, arg] = process.argv.slice(2);
  if (mode === "mcap") mcap(arg);
  else if (mode === "live") live(arg);
  else throw new Error("usage: node check.mjs mcap FILE | live ws://ADDR");
} catch (e) {
  fail(e);
}
