// Reads an MCAP file with the official TypeScript libraries and prints what it holds as JSON.
//
// usage: node read_mcap.mjs FILE.mcap
//
// Two independent passes, both validating CRCs:
//   * indexed: McapIndexedReader (summary, chunk and message indexes) -> per-topic counts,
//     schemas, metadata, and the first message of each topic decoded (protobuf through the
//     schema's FileDescriptorSet, JSON parsed), and every foxglove.FrameTransform decoded;
//   * stream:  McapStreamReader over the whole file (chunk CRCs + data-section CRC) -> counts.
// Exits 1 with a one-line message on any error.
import { open, readFile } from "node:fs/promises";

import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { FileHandleReadable } from "@mcap/nodejs";
import { loadDecompressHandlers, protobufFromBinaryDescriptor } from "@mcap/support";

function summarize(schema, channel, data) {
  if (channel.messageEncoding === "json") {
    const obj = JSON.parse(new TextDecoder().decode(data));
    return { keys: Object.keys(obj).sort() };
  }
  const root = protobufFromBinaryDescriptor(schema.data);
  const msg = root.lookupType(schema.name).decode(data);
  const out = {};
  for (const key of ["width", "height", "encoding", "format", "distortion_model", "frame_id"]) {
    if (msg[key] !== undefined && msg[key] !== "") out[key] = msg[key];
  }
  for (const key of ["parent_frame_id", "child_frame_id"]) {
    if (msg[key] !== undefined && msg[key] !== "") out[key] = msg[key];
  }
  if (msg.translation) out.translation = [msg.translation.x, msg.translation.y, msg.translation.z];
  if (msg.rotation) out.rotation = [msg.rotation.x, msg.rotation.y, msg.rotation.z, msg.rotation.w];
  if (msg.K) out.K = Array.from(msg.K);
  if (msg.data) out.dataBytes = msg.data.length;
  return out;
}

async function indexedPass(path, decompressHandlers) {
  const handle = await open(path, "r");
  try {
    const reader = await McapIndexedReader.Initialize({
      readable: new FileHandleReadable(handle),
      decompressHandlers,
    });
    const topics = {};
    for (const channel of reader.channelsById.values()) {
      const schema = reader.schemasById.get(channel.schemaId);
      topics[channel.topic] = {
        schema: schema?.name ?? "",
        schemaEncoding: schema?.encoding ?? "",
        messageEncoding: channel.messageEncoding,
        count: 0,
        first: null,
      };
    }
    let messages = 0;
    const transforms = [];
    let lastTime = -1n;
    let ordered = true;
    for await (const message of reader.readMessages({ validateCrcs: true })) {
      const channel = reader.channelsById.get(message.channelId);
      const entry = topics[channel.topic];
      entry.count += 1;
      messages += 1;
      if (message.logTime < lastTime) ordered = false;
      lastTime = message.logTime;
      if (message.logTime !== message.publishTime) throw new Error(`log_time != publish_time on ${channel.topic}`);
      const schema = reader.schemasById.get(channel.schemaId);
      if (entry.first === null) {
        entry.first = summarize(schema, channel, message.data);
      }
      if (schema?.name === "foxglove.FrameTransform") {
        transforms.push({ topic: channel.topic, ...summarize(schema, channel, message.data) });
      }
    }
    const metadata = [];
    for await (const record of reader.readMetadata()) {
      metadata.push({ name: record.name, metadata: Object.fromEntries(record.metadata) });
    }
    const statistics = reader.statistics
      ? { messageCount: Number(reader.statistics.messageCount), chunkCount: reader.statistics.chunkCount }
      : null;
    return {
      library: reader.header.library,
      chunks: reader.chunkIndexes.length,
      compression: [...new Set(reader.chunkIndexes.map((c) => c.compression))],
      messages,
      ordered,
      topics,
      metadata,
      statistics,
      transforms,
    };
  } finally {
    await handle.close();
  }
}

function streamPass(bytes, decompressHandlers) {
  const reader = new McapStreamReader({ decompressHandlers, validateCrcs: true });
  reader.append(bytes);
  const counts = {};
  const channels = new Map();
  let dataEnd = null;
  for (let record; (record = reader.nextRecord()); ) {
    if (record.type === "Channel") channels.set(record.id, record.topic);
    if (record.type === "Message") {
      const topic = channels.get(record.channelId);
      counts[topic] = (counts[topic] ?? 0) + 1;
    }
    if (record.type === "DataEnd") dataEnd = record.dataSectionCrc;
  }
  return { done: reader.done(), counts, dataSectionCrc: dataEnd };
}

async function main() {
  const path = process.argv[2];
  if (!path) throw new Error("usage: node read_mcap.mjs FILE.mcap");
  const decompressHandlers = await loadDecompressHandlers();
  const indexed = await indexedPass(path, decompressHandlers);
  const stream = streamPass(new Uint8Array(await readFile(path)), decompressHandlers);
  process.stdout.write(JSON.stringify({ indexed, stream }, null, 1) + "\n");
}

main().catch((err) => {
  process.stderr.write(`read_mcap: ${String(err?.message ?? err).split("\n")[0]}\n`);
  process.exit(1);
});
