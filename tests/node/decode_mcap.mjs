// Decode every message of a ROS 2 MCAP the way Foxglove does: @mcap/core (indexed reader, CRC
// validation), @foxglove/rosmsg to parse each schema text, @foxglove/rosmsg2-serialization to
// decode the CDR. Fails on any error, on trailing bytes, or when a message does not re-encode to
// the same bytes. Prints one JSON line: {"messages": N, "topics": {topic: count}, "schemas": [...]}
//
// usage: NODE_PATH=<dir>/node_modules node decode_mcap.mjs FILE.mcap
import { createRequire } from "node:module";
import { open } from "node:fs/promises";
import path from "node:path";

const require = createRequire(path.join(process.env.NODE_PATH ?? ".", "x.js"));
const { McapIndexedReader, McapStreamReader } = require("@mcap/core");
const { loadDecompressHandlers } = require("@mcap/support");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader, MessageWriter } = require("@foxglove/rosmsg2-serialization");

const file = process.argv[2];
const fh = await open(file, "r");
const size = (await fh.stat()).size;
const readable = {
  size: async () => BigInt(size),
  read: async (offset, length) => {
    const buf = new Uint8Array(Number(length));
    await fh.read(buf, 0, Number(length), Number(offset));
    return buf;
  },
};
const decompressHandlers = await loadDecompressHandlers();
const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
if (reader.header.profile !== "ros2") throw new Error(`profile is '${reader.header.profile}'`);

const codecs = new Map();
for (const [id, schema] of reader.schemasById) {
  if (schema.encoding !== "ros2msg") throw new Error(`schema ${schema.name}: encoding ${schema.encoding}`);
  const text = new TextDecoder().decode(schema.data);
  const defs = parse(text, { ros2: true });
  codecs.set(id, { name: schema.name, reader: new MessageReader(defs), writer: new MessageWriter(defs) });
}
const topics = {};
let n = 0;
let lastLog = -1n;
for await (const msg of reader.readMessages({ validateCrcs: true })) {
  const channel = reader.channelsById.get(msg.channelId);
  if (channel.messageEncoding !== "cdr") throw new Error(`${channel.topic}: encoding ${channel.messageEncoding}`);
  const codec = codecs.get(channel.schemaId);
  let decoded;
  try {
    decoded = codec.reader.readMessage(msg.data);
  } catch (e) {
    throw new Error(`${channel.topic} (${codec.name}) at ${msg.logTime}: ${e.message}`);
  }
  if (codec.reader.lastReadHadTrailingBytes()) {
    throw new Error(`${channel.topic} (${codec.name}) at ${msg.logTime}: trailing bytes ` +
      `(${codec.reader.lastReadByteLength()} of ${msg.data.byteLength} read)`);
  }
  const again = codec.writer.writeMessage(decoded);
  if (again.byteLength !== msg.data.byteLength || Buffer.compare(Buffer.from(again), Buffer.from(msg.data)) !== 0) {
    throw new Error(`${channel.topic}: re-encoding differs (${again.byteLength} vs ${msg.data.byteLength} bytes)`);
  }
  if (msg.logTime < lastLog) throw new Error(`${channel.topic}: log time goes backwards`);
  lastLog = msg.logTime;
  topics[channel.topic] = (topics[channel.topic] ?? 0) + 1;
  n += 1;
}
// the whole file also streams (data-section CRCs, chunk CRCs) with the streaming reader
const all = new Uint8Array(size);
await fh.read(all, 0, size, 0);
await fh.close();
const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
stream.append(all);
let records = 0;
for (let rec; (rec = stream.nextRecord()); ) records += 1;
if (!stream.done()) throw new Error("stream reader did not reach the footer");
console.log(JSON.stringify({ messages: n, topics, schemas: [...codecs.values()].map((c) => c.name), records }));
