#!/usr/bin/python3
"""scripts/gpu/gpu_check_report.py, the GPU check's report, on step outputs written here: the op
table pairs each engine case with PyTorch's of the same name and shape, every bar is judged from
them (met, not met, or not met for lack of a number), and the headline figures are the model's
wall time and the GEMM's and attention's shares of PyTorch's speed.
Run: cd /work/main && /usr/bin/python3 -m pytest -q scripts/gpu/tests/test_gpu_check_report.py
"""
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
SCRIPT = os.path.join(ROOT, "scripts", "gpu", "gpu_check_report.py")
GEMM, ATT = "4096x4096x4096", "12x64 heads, 2816 tokens"


def write(path, doc, prefix=""):
    with open(path, "w") as f:
        f.write(prefix + json.dumps(doc))


def stages(total, **named):
    return {"stages": [{"name": k, "gpu_ms": v, "wall_ms": v} for k, v in named.items()],
            "total": {"gpu_ms": total, "wall_ms_unprofiled": total * 0.9}, "first_run": {"wall_ms": 900.0}}


def run_report(tmp_path, engine_ms, torch_ms, model, ref_modes, failures=0):
    out = tmp_path
    os.makedirs(out / "tests")
    write(out / "kernels.log", {"device": "Test GPU", "kernels": ["linear, fp16 weights: gemm_coopmat.comp"]})
    write(out / "bench-ops.log", {"ops": [{"name": n, "shape": s, "ms": ms, "nmse": 1e-13, "gflops": 1.0}
                                          for (n, s), ms in engine_ms.items()]},
          prefix="device: Test GPU\n")  # a log: the JSON after other lines
    write(out / "reference_ops.json", {"ops": [{"name": n, "shape": s, "ms": ms, "gflops": 1.0}
                                               for (n, s), ms in torch_ms.items()] +
                                              [{"name": "x", "shape": "y", "error": "no fp16 on a CPU"}]})
    write(out / "bench-model-fp32.log", model[0])
    write(out / "bench-model-fp16.log", model[1])
    if len(model) > 2:
        write(out / "bench-model-fp32-texel.log", model[2])
    write(out / "reference_model.json", {"model": {"modes": ref_modes}})
    write(out / "tests" / "test_linear.json", {"tests": 18, "failures": failures, "testsuites": []})
    with open(out / "steps.rc", "w") as f:
        f.write("kernels 0\nbench-ops 0\n")
    subprocess.run([sys.executable, SCRIPT, str(out)], check=True, cwd=ROOT)
    return json.load(open(out / "report.json")), open(out / "report.md").read()


def bars(doc):
    return {b["bar"]: b["met"] for b in doc["bars"]}


def test_bars_met_and_not(tmp_path):
    engine = {("gemm_f16", GEMM): 2.0, ("gemm_f32", GEMM): 5.0, ("attention_f32", ATT): 10.0, ("attention_f16", ATT): 3.0}
    torch = {("gemm_f16", GEMM): 1.5, ("gemm_f32", GEMM): 2.0, ("attention_f32", ATT): 4.5, ("attention_f16", ATT): 1.0}
    model = (stages(100.0, image_tokens=10.0, renderer=60.0, render_rays=5.0), stages(70.0, renderer=40.0),
             stages(90.0, renderer=55.0))  # fp32 with texel inputs
    modes = {"fp32": {"total_ms": 120.0, "stages": {"decoder": 50.0}}, "bf16": {"total_ms": 30.0, "stages": {}}}
    doc, md = run_report(tmp_path, engine, torch, model, modes)
    b = bars(doc)
    assert b["gemm_f16 4096x4096x4096 >= 50% of PyTorch"]          # 1.5 / 2.0 = 0.75
    assert not b["gemm_f32 4096x4096x4096 >= 50% of PyTorch"]      # 2 / 5 = 0.4
    assert b["attention_f32 12x64 heads, 2816 tokens >= 40% of PyTorch"]   # 0.45
    assert not b["attention_f16 12x64 heads, 2816 tokens >= 40% of PyTorch"]  # 0.33
    assert b["full model: engine fp32 faster than PyTorch fp32 eager"]  # 100 < 120
    assert not b["full model: engine within 2x of PyTorch bf16"]       # best 70 > 2 * 30 (of 100, 70, 90)
    assert b["zero validation messages, every test passes"]
    assert "| renderer | 65.00 | 40.00 | 55.00 | 50.00 | 0.00 |" in md  # render_rays folded in
    assert "| **total** | 100.00 | 70.00 | 90.00 | 120.00 | 30.00 |" in md
    assert "| gemm_f32 | 4096x4096x4096 | 5.000 | 1 | 1.0e-13 | 2.000 | 1 | 0.40 |" in md


def test_missing_numbers_are_not_met(tmp_path):
    doc, md = run_report(tmp_path, {}, {}, ({}, {}), {"fp32": {"error": "failed"}}, failures=1)
    assert not any(bars(doc).values())
    assert "| **total** | - | - | - | - | - |" in md


def test_headline_figures_and_their_bars(tmp_path):
    """report.json's headline: the model's wall time without timestamps at fp32 and fp16 beside
    PyTorch's fp32 (its math stated) and bf16, GEMM and attention as shares of cuBLAS and SDPA,
    and the GPU-speed bars on them."""
    engine = {("gemm_f32", GEMM): 2.4, ("attention_f32", ATT): 10.0}
    torch = {("gemm_f32", GEMM): 2.0, ("attention_f32", ATT): 6.0}
    model = (stages(100.0, renderer=60.0), stages(50.0, renderer=30.0))
    modes = {"fp32": {"total_ms": 120.0, "math": "fp32; TF32 off for matmul and cuDNN", "stages": {}},
             "bf16": {"total_ms": 40.0, "math": "bf16", "stages": {}}}
    doc, md = run_report(tmp_path, engine, torch, model, modes)
    assert doc["model_fp32_wall_ms"] == 90.0 and doc["model_fp16_wall_ms"] == 45.0
    assert doc["torch_fp32_ms"] == 120.0 and doc["torch_bf16_ms"] == 40.0
    assert doc["torch_fp32_math"] == "fp32; TF32 off for matmul and cuDNN"
    assert abs(doc["gemm_fp32_vs_cublas"] - 2.0 / 2.4) < 1e-12 and abs(doc["attention_fp32_vs_sdpa"] - 0.6) < 1e-12
    b = bars(doc)
    assert b["full model fp32 wall <= 0.8x PyTorch fp32 (TF32 off)"]   # 90 / 120 = 0.75
    assert not b["full model fp16 wall <= PyTorch bf16"]                 # 45 > 40
    assert b["GEMM fp32 4096^3 >= 0.8 of cuBLAS"]                          # 0.83
    assert b["attention fp32 >= 0.5 of scaled_dot_product_attention"]     # 0.6
    assert "| model_fp32_wall_ms | 90.00 |" in md


def test_tuner_candidates_old_beside_new(tmp_path):
    """The tuner's kernel-choice.json (copied by the check) becomes report.json's
    kernel_candidates: every GEMM and attention candidate with its time, the chosen one marked, so
    the old kernels' times stand beside the new ones' from the same run."""
    os.makedirs(tmp_path / "x")
    out = tmp_path / "x"
    write(out / "kernel-choice.json", {"dev": {
        "gemm": {"tiles": [128, 128, 8, 8, 8, 1], "candidates": [{"tiles": [64, 64, 16, 4, 4, 0], "ms": 3.0},
                                                                 {"tiles": [128, 128, 8, 8, 8, 1], "ms": 2.0}]},
        "attention": {"tiles": [32, 32, 16], "candidates": [{"tiles": [64, 32, 0], "ms": 5.0},
                                                            {"tiles": [32, 32, 16], "ms": 1.5}]}}})
    doc, md = run_report(out, {}, {}, ({}, {}), {})
    rows = {(c["kind"], tuple(c["tiles"])): (c["ms"], c["chosen"]) for c in doc["kernel_candidates"]}
    assert rows[("gemm", (64, 64, 16, 4, 4, 0))] == (3.0, False)
    assert rows[("gemm", (128, 128, 8, 8, 8, 1))] == (2.0, True)
    assert rows[("attention", (64, 32, 0))] == (5.0, False) and rows[("attention", (32, 32, 16))] == (1.5, True)
    assert "| attention | [32, 32, 16] | 1.500 | yes |" in md
