#!/usr/bin/python3
"""Times the same SPAR model on ONNX Runtime, PyTorch eager and the engine, on the same frames.

CPU run time of the same SPAR model three ways: ONNX Runtime (npm's onnxruntime-node, CPU,
2 intra-op threads), PyTorch eager (the reference model, float32, 2 threads) and this engine on
lavapipe (`build/bin/spar-bench --model ... --json`). Prints a markdown table and writes it
to OUT/table.md, with the figures in OUT/result.json.

    /usr/bin/python3 scripts/compare/compare_onnx.py [--out build/compare-onnx] [--repeat 3]

The model: the official configuration without the semantic branch, random perturbed weights
(seed 11), 4 input views + 4 target views at 256x256, made as scripts/compare/compare_full.py makes it
(build/compare-full/full.pt, full.spar and full_photometric.json are reused when present, else
made under --out; about 1.4 GB each, and the .onnx again). The reference's forward (images ->
rendered RGB of the targets, P(dynamic) of the inputs) is exported with torch.onnx (opset 17);
torch 1.13 cannot export Tensor.tile or torch.cross, which are replaced by equivalents during the
export only. The ONNX output is checked against PyTorch eager (max abs difference).
Each runtime: one warm-up run, then the median of --repeat runs; loading / session creation apart.
ONNX Runtime runs with its SkipLayerNormFusion optimizer disabled (it crashes session creation
on this graph). PyTorch is timed in a subprocess without OPENBLAS_CORETYPE / OPENBLAS_L2_SIZE
(set on this machine; they hold OpenBLAS to AVX2); the other runtimes keep the environment.

Needs: /usr/bin/python3 with torch (1.13) and numpy, node + npm, network once (npm installs
onnxruntime-node into OUT/node), a built build/bin/spar-bench. Takes minutes; run it on an
otherwise idle machine. Not part of the test suite.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# The repository's Python roots this program imports from, found from here (nothing installed).
sys.path[:0] = [os.path.join(ROOT, d) for d in ("reference", "converter")]
ORT_VERSION = "1.30.0"
INPUTS, TARGETS = [0, 1, 2, 3], [4, 5, 6, 7]  # as spar-bench: inputs first, then targets
THREADS = 2


def die(msg):
    sys.stderr.write(f"compare_onnx: {str(msg).splitlines()[0] if str(msg) else msg}\n")
    raise SystemExit(1)


def run(cmd, env=None, cwd=None):
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=cwd)
    if r.returncode != 0:
        tail = (r.stderr.strip() or r.stdout.strip() or "no output").splitlines()[-1]
        die(f"{os.path.basename(cmd[0])} {os.path.basename(cmd[1]) if len(cmd) > 1 else ''} "
            f"failed ({r.returncode}): {tail}")
    return r.stdout


def make_model(out):
    """(checkpoint, packed, config) paths, reusing build/compare-full's when present."""
    for d in (os.path.join(ROOT, "build", "compare-full"), out):
        p = [os.path.join(d, n) for n in ("full.pt", "full.spar", "full_photometric.json")]
        if all(os.path.exists(x) for x in p):
            return p
    from spar_convert.model_config import full
    ck, packed, cfg_path = p
    cfg = full()
    cfg.use_lseg = False
    with open(cfg_path, "w") as f:
        json.dump(cfg.validate().to_dict(), f, indent=1)
    run([sys.executable, os.path.join(ROOT, "reference", "spar-reference"), "make-checkpoint", "--config",
         cfg_path, "--seed", "11", "--perturb", "--no-optimizer", "-o", ck])
    run([sys.executable, os.path.join(ROOT, "converter", "spar-convert"), "-q", ck, "--config", cfg_path,
         "-o", packed])
    return p


def load_model(ck, cfg_path):
    import torch
    from spar_reference.cli import build_model, get_config, load_checkpoint, split_state_dict
    torch.set_num_threads(THREADS)
    cfg = get_config(cfg_path, None)
    return build_model(cfg, split_state_dict(load_checkpoint(ck))[0], False), cfg


def wrapper(model):
    import torch

    class Wrapped(torch.nn.Module):
        """images [1, V, 3, H, W] -> (rgb [1, T, 3, H, W], P(dynamic) [1, K, 1, H, W])."""
        def __init__(self):
            super().__init__()
            self.m = model

        def forward(self, images):
            o = self.m(images, INPUTS, TARGETS)
            return o["rgb"], o["cv_drp_input"]["prob"]
    return Wrapped().eval()


def images(cfg):
    rng = np.random.default_rng(11)
    return rng.random((1, len(INPUTS) + len(TARGETS), 3, cfg.image_height, cfg.image_width),
                      dtype=np.float32)


def export(ck, cfg_path, onnx_path, x_path, ref_prefix):
    """Exports the wrapper; saves the input and PyTorch eager's outputs (raw float32)."""
    import torch
    model, cfg = load_model(ck, cfg_path)
    net = wrapper(model)
    x = torch.from_numpy(images(cfg))
    x.numpy().tofile(x_path)
    with torch.no_grad():
        for name, t in zip(("rgb", "p_dynamic"), net(x)):
            t.numpy().astype(np.float32).tofile(ref_prefix + name + ".bin")
        if os.path.exists(onnx_path):
            return
        tile, cross = torch.Tensor.tile, torch.cross

        def tile_(self, *dims):
            dims = tuple(dims[0]) if len(dims) == 1 and not isinstance(dims[0], int) else dims
            dims = (1,) * (self.dim() - len(dims)) + tuple(dims)
            return self.repeat(*dims)

        def cross_(a, b, dim=-1):
            a0, a1, a2 = a.unbind(dim)
            b0, b1, b2 = b.unbind(dim)
            return torch.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], dim=dim)
        torch.Tensor.tile, torch.cross = tile_, cross_
        try:
            torch.onnx.export(net, (x,), onnx_path + ".tmp", opset_version=17,
                              input_names=["images"], output_names=["rgb", "p_dynamic"])
        finally:
            torch.Tensor.tile, torch.cross = tile, cross
        os.replace(onnx_path + ".tmp", onnx_path)


def torch_worker(ck, cfg_path, repeat, result_path):
    """Runs in a subprocess (OpenBLAS unrestricted): load, one warm-up, `repeat` timed runs."""
    import torch
    t = time.perf_counter()
    model, cfg = load_model(ck, cfg_path)
    load_s = time.perf_counter() - t
    net = wrapper(model)
    x = torch.from_numpy(images(cfg))
    times = []
    with torch.no_grad():
        for _ in range(repeat + 1):
            t = time.perf_counter()
            net(x)
            times.append(time.perf_counter() - t)
    with open(result_path, "w") as f:
        json.dump({"torch": torch.__version__, "threads": torch.get_num_threads(), "load_s": load_s,
                   "warmup_s": times[0], "runs_s": times[1:],
                   "median_s": statistics.median(times[1:])}, f)


def ensure_ort(node_dir):
    if not os.path.isdir(os.path.join(node_dir, "node_modules", "onnxruntime-node")):
        os.makedirs(node_dir, exist_ok=True)
        if not os.path.exists(os.path.join(node_dir, "package.json")):
            with open(os.path.join(node_dir, "package.json"), "w") as f:
                f.write('{"name": "compare-onnx", "private": true}\n')
        run(["npm", "install", "--no-audit", "--no-fund", f"onnxruntime-node@{ORT_VERSION}"],
            env=dict(os.environ, ONNXRUNTIME_NODE_INSTALL="skip",
                     ONNXRUNTIME_NODE_INSTALL_CUDA="skip"), cwd=node_dir)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "build", "compare-onnx"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--bench", default=os.path.join(ROOT, "build", "bin", "spar-bench"))
    ap.add_argument("--torch-worker", nargs=3, metavar=("CK", "CFG", "RESULT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.torch_worker:
        return torch_worker(*args.torch_worker[:2], args.repeat, args.torch_worker[2])
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    if not os.access(args.bench, os.X_OK):
        die(f"{args.bench} not found: build the project first")
    ck, packed, cfg_path = make_model(out)
    onnx_path, x_path, ref, got = (os.path.join(out, n) for n in
                                   ("spar.onnx", "images.bin", "torch_", "ort_"))
    print(f"[1/4] exporting ONNX ({onnx_path}) ...", flush=True)
    export(ck, cfg_path, onnx_path, x_path, ref)
    with open(cfg_path) as f:
        c = json.load(f)
    h, w = c["image_height"], c["image_width"]

    print("[2/4] ONNX Runtime ...", flush=True)
    node_dir = os.path.join(out, "node")
    ensure_ort(node_dir)
    ort = json.loads(run(["node", os.path.join(ROOT, "scripts", "compare", "onnx_runtime_bench.js"), onnx_path,
                          x_path, f"1,{len(INPUTS) + len(TARGETS)},3,{h},{w}", got, "--repeat",
                          str(args.repeat), "--threads", str(THREADS)],
                         env=dict(os.environ, NODE_PATH=os.path.join(node_dir, "node_modules")))
                     .strip().splitlines()[-1])
    diffs = {n: float(np.abs(np.fromfile(ref + n + ".bin", np.float32)
                             - np.fromfile(got + n + ".bin", np.float32)).max())
             for n in ("rgb", "p_dynamic")}

    print("[3/4] PyTorch eager ...", flush=True)
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE")}
    tres = os.path.join(out, "torch_result.json")
    run([sys.executable, os.path.abspath(__file__), "--repeat", str(args.repeat), "--torch-worker",
         ck, cfg_path, tres], env=env)
    with open(tres) as f:
        pt = json.load(f)

    print("[4/4] engine (spar-bench) ...", flush=True)
    t = time.perf_counter()
    eng = json.loads(run([args.bench, "--model", packed, "--views", str(len(INPUTS)), "--targets",
                          str(len(TARGETS)), "--repeat", str(args.repeat), "--json"]))
    eng["process_s"] = time.perf_counter() - t

    note = (f"{len(INPUTS)} input + {len(TARGETS)} target views at {h}x{w}, official config without "
            f"the semantic branch, random perturbed weights; median of {args.repeat} runs after a "
            "warm-up (engine: after its first run)")
    rows = [
        ("ONNX Runtime (CPU, onnxruntime-node " + ort["onnxruntime_node"] + f", {THREADS} intra-op "
         "threads, SkipLayerNormFusion disabled)", ort["median_s"],
         f"session {ort['session_s']:.1f} s, warm-up run {ort['warmup_s']:.1f} s"),
        (f"PyTorch eager (torch {pt['torch']}, float32, {pt['threads']} threads, OpenBLAS "
         "unrestricted: no OPENBLAS_CORETYPE/L2_SIZE)", pt["median_s"],
         f"model load {pt['load_s']:.1f} s, warm-up run {pt['warmup_s']:.1f} s"),
        (f"engine on {eng['device']} (spar-bench, sum of stage GPU times)", eng["total"]["gpu_ms"] / 1e3,
         f"first run {eng['first_run']['wall_ms'] / 1e3:.1f} s wall (of it driver builds "
         f"{eng['first_run']['build_ms'] / 1e3:.1f} s); timed runs {eng['total']['wall_ms'] / 1e3:.1f} s "
         f"wall; whole process {eng['process_s']:.1f} s"),
    ]
    base = rows[0][1]
    lines = [f"{note}.", "", "| runtime | run s (median) | vs ONNX Runtime | loading / first run |",
             "|---|---|---|---|"]
    lines += [f"| {n} | {s:.2f} | {s / base:.2f}x | {extra} |" for n, s, extra in rows]
    lines += ["", f"ONNX Runtime vs PyTorch eager outputs, max abs difference: rgb {diffs['rgb']:.3g}, "
              f"P(dynamic) {diffs['p_dynamic']:.3g}."]
    table = "\n".join(lines)
    print("\n" + table)
    with open(os.path.join(out, "table.md"), "w") as f:
        f.write(table + "\n")
    with open(os.path.join(out, "result.json"), "w") as f:
        json.dump({"note": note, "onnxruntime": ort, "torch": pt, "engine": eng,
                   "max_abs_diff_onnx_vs_torch": diffs, "model": {"checkpoint": ck, "packed": packed,
                                                                  "config": cfg_path,
                                                                  "onnx": onnx_path}}, f, indent=1)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        die("interrupted")
    except Exception as e:  # one line, not a traceback
        die(f"{type(e).__name__}: {e}")
