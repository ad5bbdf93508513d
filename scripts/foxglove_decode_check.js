// Decode MCAP files the way Foxglove / Lichtblick does, with the viewer's own JSON-schema decoder.
//
// Not part of `make test` (needs Node and npm); a manual cross-check of cdgps_cli.mcap_check:
//   mkdir /tmp/fx && cd /tmp/fx && npm install @mcap/core fzstd typescript@5 @protobufjs/base64
//   git show <lichtblick>:packages/mcap-support/src/parseJsonSchema.ts > parseJsonSchema.ts
//   node -e 'const ts=require("typescript"),fs=require("fs");fs.writeFileSync("parseJsonSchema.js",
//     ts.transpileModule(fs.readFileSync("parseJsonSchema.ts","utf8"),{compilerOptions:{module:1,target:7}}).outputText)'
//   NODE_PATH=/tmp/fx/node_modules FOXGLOVE_DECODER=/tmp/fx/parseJsonSchema.js \
//     node scripts/foxglove_decode_check.js run.mcap states.mcap
// Every channel's schema goes through parseJsonSchema (a refused schema is a failure), every
// message through JSON.parse and the decoder's post-processing, and `timestamp` must equal the
// log time (a foxglove.SceneUpdate: each entity's timestamp); prints each file's first log time as a
// UTC date.  Exit 1 on any failure.
const fs = require("fs");
const { McapIndexedReader } = require("@mcap/core");
const { decompress } = require("fzstd");
const { parseJsonSchema } = require(process.env.FOXGLOVE_DECODER || "./parseJsonSchema.js");
class FileReadable {
  constructor(buf) { this.buf = buf; }
  async size() { return BigInt(this.buf.length); }
  async read(offset, size) { return this.buf.subarray(Number(offset), Number(offset + size)); }
}
(async () => {
  let total = 0, failures = 0;
  for (const path of process.argv.slice(2)) {
    const reader = await McapIndexedReader.Initialize({
      readable: new FileReadable(fs.readFileSync(path)),
      decompressHandlers: { zstd: (data, size) => decompress(data, new Uint8Array(Number(size))) },
    });
    const parsers = new Map();
    for (const [id, ch] of reader.channelsById) {
      const sc = reader.schemasById.get(ch.schemaId);
      try {
        const schema = JSON.parse(new TextDecoder().decode(sc.data));
        parsers.set(id, parseJsonSchema(schema, sc.name));
      } catch (e) { failures++; console.log(`${path} ${ch.topic}: schema refused: ${e.message}`); }
    }
    let n = 0;
    for await (const m of reader.readMessages()) {
      n++;
      try {
        const v = JSON.parse(new TextDecoder().decode(m.data));
        const p = parsers.get(m.channelId);
        if (p) p.postprocessValue(v);
        // cdgps channels: the top-level timestamp; foxglove.SceneUpdate: each entity's
        const stamps = v.timestamp ? [v.timestamp] : (v.entities || []).map((e) => e.timestamp);
        if (!stamps.length) throw new Error("no timestamp");
        for (const ts of stamps) {
          if (BigInt(ts.sec) * 1000000000n + BigInt(ts.nsec) !== m.logTime) throw new Error("timestamp != logTime");
        }
      } catch (e) { failures++; if (failures < 20) console.log(`${path}: message ${m.sequence}: ${e.message}`); }
    }
    const st = reader.statistics;
    console.log(`${path}: ${reader.channelsById.size} channels, ${n} messages, starts ${st && n ? new Date(Number(st.messageStartTime / 1000000n)).toISOString() : "-"}`);
    total += n;
  }
  console.log(`total ${total} messages, ${failures} failures`);
  process.exit(failures ? 1 : 0);
})();
