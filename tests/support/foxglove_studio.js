// Foxglove Studio's own code, under Node.js, reading what adrive writes: a recording
// (opened as Studio opens a local file: its indexed reader when the file has chunk
// indexes, else its streaming reader, both from @mcap/core) or the channels the live
// view advertises. Every channel goes through Studio's `parseChannel` and
// `parseJsonSchema` (packages/mcap-support), taken verbatim from the bundle that
// @foxglove/studio-base publishes on npm, and every message through the deserializer
// it returns. Used by tests/foxglove_studio.rs, which installs the packages.
//
// usage: node foxglove_studio.js NODE_MODULES_DIR mcap FILE
//        node foxglove_studio.js NODE_MODULES_DIR advertise FILE.json
// Prints one JSON object: how the file was read, each channel with Studio's verdict
// (its error when Studio drops it), the types it made of its schema, and its messages.

"use strict";

const fs = require("fs");
const path = require("path");
const { createRequire } = require("module");

const [modules, mode, file] = process.argv.slice(2);
const need = createRequire(path.join(path.resolve(modules), "noop.js"));

/** The text between two markers of the Studio bundle, or a loud failure. */
function slice(bundle, start, end) {
  const a = bundle.indexOf(start);
  const b = bundle.indexOf(end, a + start.length);
  if (a < 0 || b < 0) {
    throw new Error(`the Studio bundle has no ${JSON.stringify(start)} … ${JSON.stringify(end)}`);
  }
  return bundle.slice(a, b);
}

/** Studio's parseChannel, with its parseJsonSchema, from the published bundle. */
function studioParseChannel() {
  const bundlePath = need.resolve("@foxglove/studio-base/assets/index.js");
  const bundle = fs.readFileSync(bundlePath, "utf8");
  const parseJsonSchema = slice(
    bundle,
    ";// CONCATENATED MODULE: ../mcap-support/src/parseJsonSchema.ts",
    "// EXTERNAL MODULE:",
  );
  const parseChannel = slice(
    bundle,
    ";// CONCATENATED MODULE: ../mcap-support/src/parseChannel.ts",
    ";// CONCATENATED MODULE: ../mcap-support/src/index.ts",
  );
  // The JSON branch of parseChannel uses parseJsonSchema and base64 only; the other
  // encodings' helpers are never reached.
  const make = new Function(
    "base64",
    `${parseJsonSchema}\n${parseChannel}\nreturn parseChannel;`,
  );
  return make(need("@protobufjs/base64"));
}

const parseChannel = studioParseChannel();
const decoder = new TextDecoder();

/** Studio's verdict on one channel, and the types it made of its schema. */
function open(channel) {
  try {
    const parsed = parseChannel(channel);
    // Every type Studio made of the schema, with its fields (what a message path
    // such as `/steer/command.value` is checked against).
    const types = {};
    for (const [name, t] of parsed.datatypes) {
      types[name] = {};
      for (const f of t.definitions) {
        if (!f.isConstant) {
          types[name][f.name] = f.type + (f.isArray ? "[]" : "");
        }
      }
    }
    return { parsed, report: { ok: true, types } };
  } catch (e) {
    return { parsed: undefined, report: { ok: false, error: String(e.message || e) } };
  }
}

async function readMcap() {
  const { McapIndexedReader, McapStreamReader } = need("@mcap/core");
  const zstd = need("@foxglove/wasm-zstd");
  await zstd.isLoaded;
  const decompressHandlers = {
    zstd: (buffer, size) => zstd.decompress(buffer, Number(size)),
  };
  const bytes = fs.readFileSync(file);
  const readable = {
    size: async () => BigInt(bytes.length),
    read: async (offset, length) =>
      bytes.subarray(Number(offset), Number(offset) + Number(length)),
  };
  const out = { how: "", channels: {}, messages: 0, errors: [] };
  const opened = new Map();
  const channelOf = (id, topic, messageEncoding, schema) => {
    if (!opened.has(id)) {
      const channel = {
        messageEncoding,
        schema: schema && { name: schema.name, encoding: schema.encoding, data: schema.data },
      };
      const { parsed, report } = open(channel);
      out.channels[topic] = { ...report, messages: 0, deserialized: 0 };
      opened.set(id, { parsed, topic });
    }
    return opened.get(id);
  };
  const take = (c, data) => {
    out.channels[c.topic].messages += 1;
    out.messages += 1;
    if (c.parsed) {
      try {
        const value = c.parsed.deserialize(data);
        if (value == undefined || typeof value !== "object") {
          throw new Error(`not an object: ${decoder.decode(data)}`);
        }
        out.channels[c.topic].deserialized += 1;
      } catch (e) {
        if (out.errors.length < 10) out.errors.push(`${c.topic}: ${e.message}`);
      }
    }
  };
  // As Studio's McapIterableSource: indexed when the file has chunk indexes and
  // channels, else streamed from the start.
  let indexed;
  try {
    indexed = await McapIndexedReader.Initialize({ readable, decompressHandlers });
    if (indexed.chunkIndexes.length === 0 || indexed.channelsById.size === 0) {
      indexed = undefined;
    }
  } catch (e) {
    out.indexed_error = String(e.message || e);
    indexed = undefined;
  }
  if (indexed) {
    out.how = "indexed";
    for await (const m of indexed.readMessages()) {
      const ch = indexed.channelsById.get(m.channelId);
      const schema = indexed.schemasById.get(ch.schemaId);
      take(channelOf(ch.id, ch.topic, ch.messageEncoding, schema), m.data);
    }
  } else {
    out.how = "streamed";
    const reader = new McapStreamReader({ decompressHandlers });
    reader.append(bytes);
    const schemas = new Map();
    const channels = new Map();
    try {
      for (let r; (r = reader.nextRecord()); ) {
        if (r.type === "Schema") schemas.set(r.id, r);
        if (r.type === "Channel") channels.set(r.id, r);
        if (r.type === "Message") {
          const ch = channels.get(r.channelId);
          take(channelOf(ch.id, ch.topic, ch.messageEncoding, schemas.get(ch.schemaId)), r.data);
        }
      }
      out.stream_done = reader.done();
    } catch (e) {
      out.stream_error = String(e.message || e);
    }
  }
  return out;
}

function readAdvertise() {
  const adv = JSON.parse(fs.readFileSync(file, "utf8"));
  const out = { how: "advertise", channels: {}, messages: 0, errors: [] };
  const encoder = new TextEncoder();
  for (const c of adv.channels) {
    const channel = {
      messageEncoding: c.encoding,
      schema: { name: c.schemaName, encoding: c.schemaEncoding, data: encoder.encode(c.schema) },
    };
    const { parsed, report } = open(channel);
    out.channels[c.topic] = { ...report, messages: 0, deserialized: 0 };
    for (const m of (adv.messages || {})[c.topic] || []) {
      out.channels[c.topic].messages += 1;
      out.messages += 1;
      if (parsed) {
        try {
          parsed.deserialize(encoder.encode(m));
          out.channels[c.topic].deserialized += 1;
        } catch (e) {
          out.errors.push(`${c.topic}: ${e.message}`);
        }
      }
    }
  }
  return out;
}

(async () => {
  const out = mode === "mcap" ? await readMcap() : readAdvertise();
  process.stdout.write(JSON.stringify(out) + "\n");
})().catch((e) => {
  process.stderr.write(`${e.stack || e}\n`);
  process.exit(2);
});
