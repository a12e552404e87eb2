// Times an ONNX model with onnxruntime-node on the CPU (compare_onnx.py's helper).
// Not part of the test suite.
//   NODE_PATH=DIR/node_modules node scripts/compare/onnx_runtime_bench.js MODEL.onnx INPUT.bin SHAPE OUT_PREFIX \
//       [--repeat 3] [--threads 2] [--disable SkipLayerNormFusion]
// INPUT.bin: raw float32 of the model's first input, SHAPE: comma-separated dims. One warm-up
// run, then --repeat timed runs (the median is reported); every output of the last run is
// written to OUT_PREFIX<name>.bin (raw float32). Prints one JSON object.
'use strict';
const fs = require('fs');

function fail(msg) {
  process.stderr.write(`onnx_runtime_bench: ${String(msg).split('\n')[0]}\n`);
  process.exit(1);
}

async function main() {
  const argv = process.argv.slice(2);
  const opt = {repeat: 3, threads: 2, disable: 'SkipLayerNormFusion'};
  const pos = [];
  for (let i = 0; i < argv.length; ++i) {
    if (argv[i].startsWith('--')) opt[argv[i].slice(2)] = argv[++i];
    else pos.push(argv[i]);
  }
  if (pos.length !== 4) fail('usage: MODEL.onnx INPUT.bin SHAPE OUT_PREFIX [--repeat N] [--threads N]');
  const [modelPath, inputPath, shapeArg, outPrefix] = pos;
  let ort;
  try {
    ort = require('onnxruntime-node');
  } catch (e) {
    fail(`cannot load onnxruntime-node (npm install it, see scripts/compare/compare_onnx.py): ${e.message}`);
  }
  const shape = shapeArg.split(',').map(Number);
  const buf = fs.readFileSync(inputPath);
  const data = new Float32Array(buf.buffer, buf.byteOffset, buf.byteLength / 4);
  const options = {
    executionProviders: ['cpu'],
    intraOpNumThreads: Number(opt.threads),
    interOpNumThreads: 1,
    executionMode: 'sequential',
    graphOptimizationLevel: 'all',
  };
  // session config entry optimization.disable_specified_optimizers (comma-separated names)
  if (opt.disable) options.extra = {optimization: {disable_specified_optimizers: opt.disable}};
  let t = process.hrtime.bigint();
  const session = await ort.InferenceSession.create(modelPath, options);
  const sessionS = Number(process.hrtime.bigint() - t) / 1e9;
  const feeds = {[session.inputNames[0]]: new ort.Tensor('float32', data, shape)};
  t = process.hrtime.bigint();
  let out = await session.run(feeds);
  const warmupS = Number(process.hrtime.bigint() - t) / 1e9;
  const runs = [];
  for (let r = 0; r < Number(opt.repeat); ++r) {
    t = process.hrtime.bigint();
    out = await session.run(feeds);
    runs.push(Number(process.hrtime.bigint() - t) / 1e9);
  }
  for (const name of session.outputNames) {
    const d = out[name].data;
    fs.writeFileSync(`${outPrefix}${name}.bin`, Buffer.from(d.buffer, d.byteOffset, d.byteLength));
  }
  const sorted = [...runs].sort((a, b) => a - b);
  const version = require('onnxruntime-node/package.json').version;
  console.log(JSON.stringify({
    onnxruntime_node: version, threads: Number(opt.threads), disabled_optimizers: opt.disable || '',
    session_s: sessionS, warmup_s: warmupS, runs_s: runs, median_s: sorted[Math.floor(sorted.length / 2)],
    outputs: session.outputNames,
  }));
}

main().catch((e) => fail(e && e.message ? e.message : e));
