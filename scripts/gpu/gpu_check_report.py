#!/usr/bin/env python3
"""Writes the GPU check's report (report.json, report.md) from what its steps left.

scripts/gpu/gpu-check.sh's report: reads what the steps left in OUT and writes OUT/report.json
and OUT/report.md: the device and kernel plan, the tests (passed / failed, validation messages),
the op table beside PyTorch on the same GPU, the full-size model per stage beside the PyTorch
reference in fp32 and bf16, the headline figures (model wall time beside PyTorch's, GEMM and
attention against cuBLAS and SDPA), and the bars, each met or not.

    gpu_check_report.py OUT
"""
import glob
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# The repository's Python roots this program imports from, found from here (nothing installed).
sys.path[:0] = [os.path.join(ROOT, d) for d in ("reference", "converter")]
from spar_reference.cli import ENGINE_STAGE_MAP  # noqa: E402

# (engine case, shape, PyTorch case, shape, least share of PyTorch's speed): the op bars
BARS = [("gemm_f16", "4096x4096x4096", "gemm_f16", "4096x4096x4096", 0.5),
        ("gemm_f32", "4096x4096x4096", "gemm_f32", "4096x4096x4096", 0.5),
        ("attention_f32", "12x64 heads, 2816 tokens", "attention_f32", "12x64 heads, 2816 tokens", 0.4),
        ("attention_f16", "12x64 heads, 2816 tokens", "attention_f16", "12x64 heads, 2816 tokens", 0.4)]


def load_json(path):
    """A JSON document, or the outermost {...} of a log that holds one; None if neither."""
    try:
        text = open(path).read()
    except OSError:
        return None
    try:
        return json.loads(text)
    except ValueError:
        a, b = text.find("{"), text.rfind("}")
        if a < 0 or b < a:
            return None
        try:
            return json.loads(text[a:b + 1])
        except ValueError:
            return None


def tests(out):
    """Per program: tests and failures (a test fails on any validation message it did not
    provoke on purpose: tests/test_support.h, EngineTest)."""
    rows = []
    for f in sorted(glob.glob(os.path.join(out, "tests", "*.json"))):
        d = load_json(f) or {}
        name = os.path.splitext(os.path.basename(f))[0]
        failed = [f"{s['name']}.{t['name']}" for s in d.get("testsuites", []) for t in s.get("testsuite", [])
                  if t.get("failures")]
        rows.append({"program": name, "tests": d.get("tests", 0), "failures": d.get("failures", 0),
                     "failed": failed[:10]})
    return rows


def headline(models, modes, bench, ref_by):
    """The figures a user compares first: the model's wall time without timestamps (what a user
    waits for) at fp32 and fp16 beside PyTorch's fp32 (TF32 off) and bf16 eager, and the share of
    PyTorch's speed the engine's fp32 GEMM (4096^3, against cuBLAS) and attention (against
    scaled_dot_product_attention) reach."""
    def share(name, shape):
        e = next((o for o in bench.get("ops", []) if o["name"] == name and o["shape"] == shape), None)
        t = ref_by.get((name, shape))
        return t["ms"] / e["ms"] if e and t and e.get("ms") else None
    return {"model_fp32_wall_ms": models["fp32"].get("total", {}).get("wall_ms_unprofiled"),
            "model_fp16_wall_ms": models["fp16"].get("total", {}).get("wall_ms_unprofiled"),
            "torch_fp32_ms": modes.get("fp32", {}).get("total_ms"),
            "torch_bf16_ms": modes.get("bf16", {}).get("total_ms"),
            "torch_fp32_math": modes.get("fp32", {}).get("math"),
            "torch_bf16_math": modes.get("bf16", {}).get("math"),
            "gemm_fp32_vs_cublas": share("gemm_f32", "4096x4096x4096"),
            "attention_fp32_vs_sdpa": share("attention_f32", "12x64 heads, 2816 tokens")}


def headline_bars(h):
    """The GPU-speed issue's bars on the headline figures."""
    def ratio(a, b):
        return a / b if a and b else None
    rows = [("full model fp32 wall <= 0.8x PyTorch fp32 (TF32 off)", ratio(h["model_fp32_wall_ms"], h["torch_fp32_ms"]), 0.8, True),
            ("full model fp16 wall <= PyTorch bf16", ratio(h["model_fp16_wall_ms"], h["torch_bf16_ms"]), 1.0, True),
            ("GEMM fp32 4096^3 >= 0.8 of cuBLAS", h["gemm_fp32_vs_cublas"], 0.8, False),
            ("attention fp32 >= 0.5 of scaled_dot_product_attention", h["attention_fp32_vs_sdpa"], 0.5, False)]
    return [{"bar": bar, "share": v, "met": v is not None and (v <= limit if at_most else v >= limit)}
            for bar, v, limit, at_most in rows]


def candidate_rows(choice):
    """Every candidate the GPU tuner timed (kernel-choice.json: one entry per device), as rows
    {"kind", "tiles", "ms", "chosen"}: the old kernels (the GEMM one k step at a time,
    attention_tiled.comp with lanes 0) beside the new ones on the same device and workload."""
    rows = []
    for entry in (choice or {}).values():
        for kind in ("gemm", "attention", "coopmat"):
            part = entry.get(kind) or {}
            for c in part.get("candidates", []):
                rows.append({"kind": kind, "tiles": c.get("tiles"), "ms": c.get("ms"),
                             "chosen": c.get("tiles") == part.get("tiles")})
    return rows


def engine_stages(doc):
    s = {x["name"]: x["gpu_ms"] for x in doc.get("stages", [])}
    s["renderer"] = s.get("renderer", 0.0) + s.pop("render_rays", 0.0)
    return s


def main(argv):
    out = argv[1]
    steps = {}
    if os.path.exists(os.path.join(out, "steps.rc")):
        for line in open(os.path.join(out, "steps.rc")):
            name, rc = line.split()
            steps[name] = int(rc) if rc.lstrip("-").isdigit() else rc  # or "skipped"
    kernels = load_json(os.path.join(out, "kernels.log")) or {}
    bench = load_json(os.path.join(out, "bench-ops.log")) or {}
    ref_ops = load_json(os.path.join(out, "reference_ops.json")) or {}
    models = {p: load_json(os.path.join(out, f"bench-model-{p}.log")) or {} for p in ("fp32", "fp16", "fp32-texel")}
    ref_model = (load_json(os.path.join(out, "reference_model.json")) or {}).get("model", {})
    test_rows = tests(out)

    md = [f"# GPU check: {kernels.get('device', '?')}", ""]
    md.append("Steps: " + ", ".join(f"{k} {'ok' if v == 0 else v if isinstance(v, str) else f'exit {v}'}"
                                    for k, v in steps.items()))
    md += ["", "## Kernel plan", ""] + [f"    {line}" for line in kernels.get("kernels", [])]
    candidates = candidate_rows(load_json(os.path.join(out, "kernel-choice.json")))
    if candidates:
        md += ["", "## Candidates the tuner timed (GEMM: BM,BN,BK,TM,TN,PIPELINED; attention: QUERIES,KEYS,LANES)", "",
               "| kernel | tiles | ms | chosen |", "|---|---|---|---|"]
        md += [f"| {c['kind']} | {c['tiles']} | {c['ms']:.3f} | {'yes' if c['chosen'] else ''} |" for c in candidates]
    # spar selftest on the device (spar-bench --selftest): its table as it printed it.
    selftest_log = os.path.join(out, "selftest.log")
    selftest = open(selftest_log, errors="replace").read().splitlines() if os.path.exists(selftest_log) else []
    if selftest:
        md += ["", "## spar selftest", ""] + [f"    {line}" for line in selftest]
    md += ["", "## Tests (validation layer on: a test fails on any message it did not provoke on purpose)", "",
           "| program | tests | failed |", "|---|---|---|"]
    for r in test_rows:
        md.append(f"| {r['program']} | {r['tests']} | {r['failures']}"
                  f"{' (' + ', '.join(r['failed']) + ')' if r['failed'] else ''} |")

    ref_by = {(o["name"], o["shape"]): o for o in ref_ops.get("ops", []) if "ms" in o}
    md += ["", "## Ops: engine beside PyTorch on the same device", "",
           "| op | shape | engine ms | engine GFLOPS | NMSE | PyTorch ms | PyTorch GFLOPS | engine / PyTorch |",
           "|---|---|---|---|---|---|---|---|"]
    rows = []
    for o in bench.get("ops", []):
        r = ref_by.get((o["name"], o["shape"]))
        ratio = (r["ms"] / o["ms"]) if r and o["ms"] else None
        rows.append({"op": o["name"], "shape": o["shape"], "engine_ms": o["ms"], "engine_gflops": o.get("gflops"),
                     "nmse": o["nmse"], "torch_ms": r["ms"] if r else None,
                     "torch_gflops": r["gflops"] if r else None, "ratio": ratio})
        gf = o.get("gflops")
        rate = f"{gf:.0f}" if gf is not None else f"{o.get('gbps', 0):.1f} GB/s"
        theirs = f"{r['ms']:.3f} | {r['gflops']:.0f} | {ratio:.2f}" if r else " | | "
        md.append(f"| {o['name']} | {o['shape']} | {o['ms']:.3f} | {rate} | {o['nmse']:.1e} | {theirs} |")
    bars = []
    for e_name, e_shape, t_name, t_shape, least in BARS:
        e = next((o for o in bench.get("ops", []) if o["name"] == e_name and o["shape"] == e_shape), None)
        t = ref_by.get((t_name, t_shape))
        share = t["ms"] / e["ms"] if e and t and e["ms"] else None
        bars.append({"bar": f"{e_name} {e_shape} >= {least:.0%} of PyTorch", "share": share,
                     "met": share is not None and share >= least})

    md += ["", "## Full-size model, 4 inputs + 4 targets: GPU ms per stage", ""]
    modes = ref_model.get("modes", {})
    e32, e16, e32t = engine_stages(models["fp32"]), engine_stages(models["fp16"]), engine_stages(models["fp32-texel"])
    md += ["| stage | engine fp32 | engine fp16 | engine fp32, texel inputs | PyTorch fp32 | PyTorch bf16 |",
           "|---|---|---|---|---|---|"]
    for stage, refs in ENGINE_STAGE_MAP:
        r32 = sum(modes.get("fp32", {}).get("stages", {}).get(x, 0.0) for x in refs)
        r16 = sum(modes.get("bf16", {}).get("stages", {}).get(x, 0.0) for x in refs)
        if not (e32.get(stage) or e16.get(stage) or r32 or r16):
            continue
        md.append(f"| {stage} | {e32.get(stage, 0):.2f} | {e16.get(stage, 0):.2f} | {e32t.get(stage, 0):.2f} | "
                  f"{r32:.2f} | {r16:.2f} |")
    t32 = models["fp32"].get("total", {}).get("gpu_ms")
    t16 = models["fp16"].get("total", {}).get("gpu_ms")
    r32 = modes.get("fp32", {}).get("total_ms")
    rb16 = modes.get("bf16", {}).get("total_ms")
    fmt = lambda v: f"{v:.2f}" if v is not None else "-"  # noqa: E731
    t32t = models["fp32-texel"].get("total", {}).get("gpu_ms")
    md.append(f"| **total** | {fmt(t32)} | {fmt(t16)} | {fmt(t32t)} | {fmt(r32)} | {fmt(rb16)} |")
    md.append(f"\nFirst run (weights, kernels): engine fp32 {fmt(models['fp32'].get('first_run', {}).get('wall_ms'))} ms, "
              f"PyTorch fp32 {fmt(modes.get('fp32', {}).get('first_run_ms'))} ms")
    bars.append({"bar": "full model: engine fp32 faster than PyTorch fp32 eager", "share": (r32 / t32) if t32 and r32 else None,
                 "met": bool(t32 and r32 and t32 < r32)})
    best = min(x for x in (t32, t16, t32t) if x) if (t32 or t16 or t32t) else None
    bars.append({"bar": "full model: engine within 2x of PyTorch bf16", "share": (rb16 / best) if best and rb16 else None,
                 "met": bool(best and rb16 and best <= 2 * rb16)})
    head = headline(models, modes, bench, ref_by)
    bars += headline_bars(head)
    md += ["", "## What a user waits for (wall time without timestamps)", "",
           "| figure | value |", "|---|---|"] + [f"| {k} | {fmt(v) if not isinstance(v, str) else v} |" for k, v in head.items()]
    bars.append({"bar": "zero validation messages, every test passes",
                 "share": None, "met": test_rows != [] and all(r["failures"] == 0 for r in test_rows)})
    md += ["", "## Bars", "", "| bar | figure | met |", "|---|---|---|"]
    for b in bars:
        md.append(f"| {b['bar']} | {fmt(b['share'])} | {'yes' if b['met'] else 'no'} |")
    verdict = next((l for l in reversed(selftest) if l.startswith("verdict:")), None)
    doc = {"device": kernels.get("device"), **head, "kernels": kernels.get("kernels"), "kernel_candidates": candidates,
           "selftest": verdict, "steps": steps,
           "tests": test_rows,
           "ops": rows, "model": {"engine_fp32": models["fp32"],
           "engine_fp16": models["fp16"], "engine_fp32_texel": models["fp32-texel"], "reference": ref_model},
           "bars": bars}
    with open(os.path.join(out, "report.json"), "w") as f:
        json.dump(doc, f, indent=1)
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write("\n".join(md) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
