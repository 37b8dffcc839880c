// Read an MCAP file with Foxglove's own TypeScript libraries (as Foxglove Studio does) and print
// a JSON summary for tests/io/test_conventions.py: the streaming reader in file order (log time must
// never go backwards), the indexed reader, and every message decoded with the file's schemas.
// Usage: node foxglove_read.mjs FILE.mcap  (NODE_PATH: a node_modules with @mcap/core, @mcap/support,
// @foxglove/rosmsg and @foxglove/rosmsg2-serialization)
import { readFileSync } from "node:fs";
import { createRequire } from "node:module";

const require = createRequire(process.env.NODE_PATH + "/");
const { McapStreamReader, McapIndexedReader } = require("@mcap/core");
const { loadDecompressHandlers } = require("@mcap/support");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");

const bytes = new Uint8Array(readFileSync(process.argv[2]));
const decompressHandlers = await loadDecompressHandlers();

const schemas = new Map();
const channels = new Map();
const readers = new Map();
const out = { topics: {}, first: {}, backwards: 0, maxQuatNormError: 0, channelMetadata: {}, tfStatic: [], jointNames: null, indexedCount: 0 };
let lastLogTime = -1n;

const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
stream.append(bytes);
for (let record; (record = stream.nextRecord()); ) {
  if (record.type === "Schema") schemas.set(record.id, record);
  else if (record.type === "Channel") {
    channels.set(record.id, record);
    out.channelMetadata[record.topic] = Object.fromEntries(record.metadata);
  } else if (record.type === "Message") {
    const channel = channels.get(record.channelId);
    const schema = schemas.get(channel.schemaId);
    if (!readers.has(schema.id)) {
      readers.set(schema.id, new MessageReader(parse(new TextDecoder().decode(schema.data), { ros2: true })));
    }
    const msg = readers.get(schema.id).readMessage(record.data);
    if (record.logTime < lastLogTime) out.backwards += 1;
    lastLogTime = record.logTime;
    out.topics[channel.topic] = (out.topics[channel.topic] ?? 0) + 1;
    if (!(channel.topic in out.first)) out.first[channel.topic] = record.logTime.toString();
    if (schema.name === "sensor_msgs/msg/Imu") {
      const q = msg.orientation;
      const norm = Math.hypot(q.x, q.y, q.z, q.w);
      out.maxQuatNormError = Math.max(out.maxQuatNormError, Math.abs(norm - 1));
    }
    if (channel.topic === "/tf_static") {
      out.tfStatic = msg.transforms.map((t) => [t.header.frame_id, t.child_frame_id]);
    }
    if (channel.topic === "/joint_states" && out.jointNames === null) out.jointNames = msg.name;
  }
}

const indexed = await McapIndexedReader.Initialize({
  readable: { size: async () => BigInt(bytes.length), read: async (offset, length) => bytes.slice(Number(offset), Number(offset + length)) },
  decompressHandlers,
});
for await (const _message of indexed.readMessages()) out.indexedCount += 1;
console.log(JSON.stringify(out));
