#!/usr/bin/python3
"""The code of ours in the device call's scripts (scripts/gpu/gpu-session.sh, gpu-check.sh,
gpu-train.sh, gpu_reference_bench.py), in seconds, without the check or the training: each
script, copied unchanged into a temporary repository, runs against stand-ins for what it calls
(the bundle's programs and loader, spar-train and the other converter tools, python3,
nvidia-smi, nproc, taskset, timeout), and what it does with their results is checked: argument
checks, the NVIDIA driver manifest, the steps' limits and the skipping past the deadline, the
status lines, what comes back (at most 8 files, under 16 MiB, two folders down; the weights in
parts that `unpack` puts back together bit for bit), `unpack`'s report and model.
The rehearsals (ctest -C rehearsal -L device_rehearsal) run the same scripts for real on this CPU.
Run: cd /work/main && /usr/bin/python3 -m pytest -q scripts/gpu/tests/test_device_call_scripts.py
"""
import io
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tarfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
SCRIPTS = os.path.join(ROOT, "scripts", "gpu")
MIB = 1 << 20

# gpu-check.sh's programs, as its `bins`, `op_tests` and `model_tests` name them
OP_TESTS = ["test_linear", "test_attention", "test_conv2d", "test_conv_transpose2d", "test_norm",
            "test_reduce_channels", "test_patchify", "test_pool", "test_resize", "test_transformer_block",
            "test_unary", "test_binary", "test_copy2d", "test_rope", "test_embedding", "test_runtime",
            "test_count_nonfinite", "test_kernel_plan", "test_plucker_rays"]
MODEL_TESTS = ["test_dino_v3", "test_cv_drp"]
BINS = ["spar-bench"] + OP_TESTS + ["test_coopmat"] + MODEL_TESTS
STEP_LIMITS = {"kernels": 120, "selftest": 120, "op-goldens": 120, "reference-ops": 240, "reference-model": 420, "report": 60}  # others 300 s


def check_steps(coopmat, report=True):
    """gpu-check.sh run's steps in order (test_coopmat where the device has cooperative matrices)."""
    return (["kernels", "selftest", "op-goldens"] + [f"test-{t}" for t in OP_TESTS] + (["test-test_coopmat"] if coopmat else []) +
            ["bench-ops", "reference-ops", "make-model", "bench-model-fp32", "bench-model-fp16", "bench-model-fp32-texel",
             "reference-model",
             "goldens"] + [f"test-{t}" for t in MODEL_TESTS] + (["report"] if report else []))

VARIANTS = {  # gpu-train.sh's variants on a GPU: name -> options besides the shared ones
    "b8-lr6e-4": "--batch 8 --lr 6e-4 --warmup 100",
    "b16-lr1e-3": "--batch 16 --lr 1e-3 --warmup 200",
    "b16-lr1e-3-pose": "--batch 16 --lr 1e-3 --warmup 200 --pose-loss 1",
    "b32-lr1.5e-3": "--batch 32 --lr 1.5e-3 --warmup 200",
    "b16-lr1e-3-st192": "--batch 16 --lr 1e-3 --warmup 200 --scene-tokens 192",
}

# --- stand-ins ---------------------------------------------------------------------------------
# Every stand-in appends a line to $STUB_LOG: "NAME ARGS | what it saw".

# python3 on the device machine (and $PYTHON): inline code is answered here; a script runs with
# the real interpreter (a stand-in script of the temporary repository, or the real report);
# gpu-train.sh's write-back (python3 - ...) runs for real only where STUB_REAL_WRITEBACK is set.
PYTHON3 = r"""#!/bin/bash
case "${1:-}" in
  -c) case "$2" in
        *ScenePool*) echo "python3 -c ScenePool" >> "$STUB_LOG"; echo "stub: scene pool";;
        *model_config*) echo "python3 -c model_config" >> "$STUB_LOG"; echo '{}' > "$3";;
        *) echo "torch stub numpy stub cuda True";;
      esac;;
  -) echo "python3 - ${*:2}" >> "$STUB_LOG"
     [ -n "${STUB_REAL_WRITEBACK:-}" ] && exec /usr/bin/python3 "$@"
     cat > /dev/null; echo "stub: no write-back in this test" >&2; exit 1;;
  *) exec /usr/bin/python3 "$@";;
esac
"""
# training/spar-train, spar-scenes, spar-reference, spar-convert, tests/python/make_spar_goldens.py,
# tests/python/make_op_goldens.py, scripts/gpu/gpu_reference_bench.py of the temporary repository: one file, told apart by its name.
TOOL = r"""import json, os, sys
name, a = os.path.basename(sys.argv[0]), sys.argv[1:]
opt = lambda k: a[a.index(k) + 1] if k in a else None
with open(os.environ["STUB_LOG"], "a") as f:
    f.write(name + " " + json.dumps(a) + "\n")
if name == "spar-scenes":
    os.makedirs(opt("--out"))
elif name in ("spar-reference", "spar-convert"):
    open(opt("-o"), "w").write(name + " output\n")
elif name in ("make_spar_goldens.py", "make_op_goldens.py"):
    os.makedirs(a[0])
elif name == "gpu_reference_bench.py":
    doc = {"tool": name}
    if "--ops" in a:
        doc["ops"] = [{"name": "gemm_f32", "shape": "1024x1024x1024", "ms": 4.0, "gflops": 500.0}]
    else:
        doc["model"] = {"modes": {"fp32": {"total_ms": 40.0, "stages": {"renderer": 30.0}},
                                  "bf16": {"total_ms": 10.0, "stages": {"renderer": 8.0}}}}
    json.dump(doc, open(opt("--out"), "w"))
elif name == "gpu_check_report.py":  # where a test does not need the real report
    open(os.path.join(a[0], "report.md"), "w").write("# stub report\n")
elif name == "spar-train":
    out = opt("--out")
    variant = os.path.basename(out)
    os.makedirs(out, exist_ok=True)
    open(os.path.join(out, "train_log.txt"), "w").write(f"{variant}: trained\n")
    json.dump({"variant": variant}, open(os.path.join(out, "config.json"), "w"))
    psnr = json.loads(os.environ.get("STUB_PSNR", "{}")).get(variant, 15.0)
    with open(os.path.join(out, "curve.jsonl"), "w") as f:
        for step in (5, 10):
            f.write(json.dumps({"step": step, "minutes": step / 10, "psnr": psnr - 10 / step,
                                "psnr_nearest_input": 12.0, "ssim": None, "sem_miou": 0.25,
                                "mask_miou": 0.5}) + "\n")
    if variant in os.environ.get("STUB_FAILING_VARIANTS", "").split():
        print(f"stub: {variant} ran out of memory")
        sys.exit(1)
    if opt("--teacher") is None:
        open(os.path.join(out, "teacher.pt"), "w").write("teacher made by " + " ".join(a))
        print("teachers: stub text encoder and LSeg")
    ckpts = json.loads(os.environ.get("STUB_CHECKPOINTS", "{}"))
    if variant in ckpts:
        os.symlink(ckpts[variant], os.path.join(out, "checkpoint.pt"))
"""
# the bundle's programs (one script, told apart by its name) and its dynamic loader
BUNDLE_BIN = r"""#!/bin/sh
name=${0##*/}
echo "bin $name $* | kernels=${SPAR_KERNELS-} inputs=${SPAR_INPUTS-} measure=${SPAR_MEASURE_KERNELS-} shards=${GTEST_TOTAL_SHARDS-}/${GTEST_SHARD_INDEX-} driver=${VK_DRIVER_FILES-} icd=${VK_ICD_FILENAMES-} layers=${VK_LAYER_PATH-} goldens=${SPAR_GOLDENS_DIR-} op_goldens=${SPAR_OP_GOLDENS_DIR-}" >> "$STUB_LOG"
case $name in
  spar-bench)
    case "$*" in
      *--list-devices*) echo "0: Stub GPU";;
      *--list-kernels*) echo '{"device": "Stub GPU", "kernels": ["linear, fp16 weights: gemm_coopmat.comp"]}';;
      *--selftest*) echo "verdict: PASS (29 of 29 checks passed)";;
      *--model*) ms=12.5; case "$*" in *fp16*) ms=7.5;; esac
        echo "model: stub"
        echo "{\"stages\": [{\"name\": \"renderer\", \"gpu_ms\": $ms}], \"total\": {\"gpu_ms\": $ms}}";;
      *) echo '{"ops": [{"name": "gemm_f32", "shape": "1024x1024x1024", "ms": 2.0, "nmse": 1e-13, "gflops": 1000.0}]}';;
    esac;;
  test_*)
    for a; do case $a in --gtest_output=json:*) json=${a#--gtest_output=json:};; esac; done
    f=0
    case " ${STUB_FAILING_TESTS-} " in *" $name "*) f=1;; esac
    echo "{\"tests\": 3, \"failures\": $f, \"testsuites\": []}" > "$json"
    echo "$name: 3 tests, $f failed"
    exit $f;;
esac
"""
LOADER = r"""#!/bin/sh
echo "ld $2" >> "$STUB_LOG"
shift 2
exec "$@"
"""
PATH_STUBS = {
    "python3": PYTHON3,
    "nvidia-smi": '#!/bin/sh\necho "Stub H200, 143771 MiB, 570.00"\n',
    "nproc": '#!/bin/sh\necho "${STUB_NPROC:-2}"\n',
    "taskset": '#!/bin/sh\necho "taskset $2 omp=${OMP_NUM_THREADS-} $3 $4 $5" >> "$STUB_LOG"\nshift 2\nexec "$@"\n',
    "timeout": '#!/bin/sh\necho "timeout $1" >> "$STUB_LOG"\nexec /usr/bin/timeout "$@"\n',
}
# gpu-session.sh's two callees, where a test looks at gpu-session.sh alone
CHECK_CALLEE = r"""#!/bin/bash
echo "gpu-check $* | OUT=${OUT-} secs=${GPU_CHECK_SECONDS-} omp=${OMP_NUM_THREADS-}" >> "$STUB_LOG"
if [ "$1" = pack ]; then
  mkdir -p .gpucheck && echo bundle > .gpucheck/bundle.tar.xz; exit "${STUB_CHECK_RC:-0}"
fi
mkdir -p "$OUT"
for f in report.md report.json steps.log gpu-check-all.tar.xz; do echo "check's $f" > "$OUT/$f"; done
echo "check: last words"
exit "${STUB_CHECK_RC:-0}"
"""
TRAIN_CALLEE = r"""#!/bin/bash
echo "gpu-train $* | OUT=$OUT secs=${GPU_TRAIN_SECONDS-} teacher=${GPU_TRAIN_TEACHER-} work=${GPU_TRAIN_WORK-}" >> "$STUB_LOG"
if [ "$1" = pool ]; then
  echo "pool: last words"; exit "${STUB_POOL_RC:-0}"
fi
echo "[stub] training" >> "$OUT/steps.log"
echo "| variant |" > "$OUT/summary.md"
echo "training: last words"
exit "${STUB_TRAIN_RC:-0}"
"""


def write(path, text, mode=0o644):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.write(text)
    os.chmod(path, mode)


def make_bundle(path):
    """.gpucheck/bundle.tar.xz as gpu-check.sh pack lays it out: bin/, runtime/, layers/."""
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with tarfile.open(path, "w:xz") as tar:
        def add(name, text, mode=0o755):
            info = tarfile.TarInfo(name)
            data = text.encode()
            info.size, info.mode = len(data), mode
            tar.addfile(info, io.BytesIO(data))
        for b in BINS:
            add("bin/" + b, BUNDLE_BIN)
        add("runtime/ld-linux-x86-64.so.2", LOADER)
        add("layers/VkLayer_khronos_validation.json", "{}\n", 0o644)


class Repo:
    """A temporary copy of the repository's device-call scripts with stand-ins around them."""

    def __init__(self, base, real=("gpu-session.sh", "gpu-check.sh", "gpu-train.sh"), report=False,
                 bundle=True):
        self.base = str(base)
        self.root = os.path.join(self.base, "repo")
        self.log = os.path.join(self.base, "stub.log")
        self.stubs = os.path.join(self.base, "stubs")
        for s in real:
            write(os.path.join(self.root, "scripts", "gpu", s), open(os.path.join(SCRIPTS, s)).read())
        callees = {"gpu-check.sh": CHECK_CALLEE, "gpu-train.sh": TRAIN_CALLEE}
        for s, text in callees.items():
            if s not in real:
                write(os.path.join(self.root, "scripts", "gpu", s), text, 0o755)
        if report:
            write(os.path.join(self.root, "scripts", "gpu", "gpu_check_report.py"),
                  open(os.path.join(SCRIPTS, "gpu_check_report.py")).read())
        else:
            write(os.path.join(self.root, "scripts", "gpu", "gpu_check_report.py"), TOOL)
        for rel in ("training/spar-train", "scenes/spar-scenes", "reference/spar-reference",
                    "converter/spar-convert", "tests/python/make_spar_goldens.py", "tests/python/make_op_goldens.py",
                    "scripts/gpu/gpu_reference_bench.py"):
            write(os.path.join(self.root, rel), TOOL)
        for rel in ("scripts/setup/pythonpath.sh", "pytest.ini"):  # what the scripts read as they are
            write(os.path.join(self.root, rel), open(os.path.join(ROOT, rel)).read())
        # the real report imports the reference (its stage names), which imports the converter
        for rel in ("reference/spar_reference", "converter/spar_convert"):
            os.symlink(os.path.join(ROOT, rel), os.path.join(self.root, rel))
        for name, text in PATH_STUBS.items():
            write(os.path.join(self.stubs, name), text, 0o755)
        if bundle:
            make_bundle(os.path.join(self.root, ".gpucheck", "bundle.tar.xz"))
        open(self.log, "w").close()
        self.out = os.path.join(self.base, "out")
        self.check_work = os.path.join(self.base, "check-work")
        self.train_work = os.path.join(self.base, "train-work")
        # a clean environment: nothing of the caller's (DIR, OUT, VK_DRIVER_FILES) leaks in, and no
        # NVIDIA driver but one a test makes (the host's, on a GPU machine, is never seen)
        self.env = {"PATH": f"{self.stubs}:/usr/local/bin:/usr/bin:/bin", "HOME": self.base, "LC_ALL": "C",
                    "STUB_LOG": self.log, "PYTHON": os.path.join(self.stubs, "python3"),
                    "OUT": self.out,
                    "GPU_CHECK_WORK": self.check_work, "GPU_TRAIN_WORK": self.train_work,
                    "GPU_CHECK_NVIDIA_ROOT": os.path.join(self.base, "no-nvidia")}

    def run(self, script, *args, **env):
        e = dict(self.env)
        e.update({k: str(v) for k, v in env.items() if v is not None})
        for k in [k for k, v in env.items() if v is None]:
            e.pop(k, None)
        return subprocess.run(["bash", os.path.join(self.root, "scripts", "gpu", script)] + list(args), env=e,
                              capture_output=True, text=True, timeout=120)

    def records(self, prefix):
        return [line.rstrip("\n")[len(prefix):] for line in open(self.log) if line.startswith(prefix)]

    def tool_calls(self, name):
        return [json.loads(line) for line in self.records(name + " ")]


def files_under(d):
    return sorted(os.path.relpath(os.path.join(p, f), d) for p, _, fs in os.walk(d) for f in fs)


def everything_under(d):
    return sorted(os.path.relpath(os.path.join(p, f), d) for p, ds, fs in os.walk(d) for f in ds + fs)


def steps_rc(work):
    return [tuple(line.split()) for line in open(os.path.join(work, "out", "steps.rc"))]


def assert_fits_device_tool(out):
    """What the device tool brings back: at most 8 files, none over 16 MiB, two folders down."""
    files = files_under(out)
    assert 0 < len(files) <= 8, files
    big = [f for f in files if os.path.getsize(os.path.join(out, f)) > 16 * MIB]
    assert not big, big
    deep = [f for f in files if f.count("/") > 2]
    assert not deep, deep
    return files


# --- argument checks ----------------------------------------------------------------------------

USAGE_ERRORS = [
    ("gpu-session.sh", []), ("gpu-session.sh", ["bogus"]), ("gpu-session.sh", ["run", "--gpu"]),
    ("gpu-session.sh", ["run", "--cpu", "extra"]), ("gpu-session.sh", ["unpack"]),
    ("gpu-check.sh", []), ("gpu-check.sh", ["unpack"]), ("gpu-check.sh", ["run", "--cpu-coopmatt"]),
    ("gpu-check.sh", ["run", "--cpu", "--cpu-coopmat"]),
    ("gpu-train.sh", []), ("gpu-train.sh", ["train"]), ("gpu-train.sh", ["run", "--cpus"]),
    ("gpu-train.sh", ["pool", "--gpu"]), ("gpu-train.sh", ["unpack"]), ("gpu-train.sh", ["unpack", "back"]),
]


def test_bad_arguments_are_one_line_errors_and_write_nothing(tmp_path):
    repo = Repo(tmp_path / "r", bundle=False)
    before = everything_under(tmp_path)
    for script, args in USAGE_ERRORS:
        r = repo.run(script, *args, GPU_SESSION_DEST=tmp_path / "back", GPU_SESSION_TEACHER=tmp_path / "t.pt")
        assert r.returncode != 0, (script, args)
        assert r.stdout == "" and len(r.stderr.strip().splitlines()) == 1, (script, args, r.stdout, r.stderr)
        assert "usage" in r.stderr, (script, args, r.stderr)
        assert everything_under(tmp_path) == before, (script, args)
        assert not os.path.exists(repo.check_work) and not os.path.exists(repo.train_work)


def test_missing_inputs_are_one_line_errors(tmp_path):
    repo = Repo(tmp_path / "r", bundle=False)
    r = repo.run("gpu-session.sh", "run", GPU_SESSION_TEACHER=tmp_path / "none.pt")
    assert r.returncode == 1 and r.stderr.strip() == f"gpu-session: no {tmp_path}/none.pt (run 'pack' here first)"
    r = repo.run("gpu-check.sh", "run")
    assert r.returncode == 1
    assert r.stderr.strip() == "gpu-check: no .gpucheck/bundle.tar.xz (run 'pack' here first)"
    make_bundle(os.path.join(repo.root, ".gpucheck", "bundle.tar.xz"))
    r = repo.run("gpu-check.sh", "run", "--cpu-coopmat", DIR=tmp_path / "no-lavapipe")
    assert r.returncode == 1 and r.stderr.strip() == \
        f"gpu-check: no lavapipe 26.1 in {tmp_path}/no-lavapipe (bash scripts/portability/coopmat-lavapipe.sh)"
    assert repo.records("bin ") == []  # no program ran


def test_reference_bench_arguments(tmp_path):
    """gpu_reference_bench.py: --ops or --checkpoint, and --out, are required (before PyTorch loads)."""
    script = os.path.join(SCRIPTS, "gpu_reference_bench.py")
    for args in (["--out", str(tmp_path / "x.json")], ["--ops"], ["--ops", "--repeat", "two", "--out", "y"]):
        r = subprocess.run([sys.executable, script] + args, capture_output=True, text=True, cwd=tmp_path, timeout=60)
        assert r.returncode == 2 and r.stderr.splitlines()[-1].startswith("gpu_reference_bench.py: error:"), r.stderr
    assert r.stdout == "" and os.listdir(tmp_path) == []


def test_reference_bench_measurement_helpers():
    """One case that cannot run is an error entry, not the end of the run; GFLOPS from the median ms."""
    import gpu_reference_bench as grb  # scripts/gpu is one of pytest.ini's roots

    def fails():
        raise RuntimeError('"addmm_impl_cpu_" not implemented for \'Half\'\nmore lines')
    assert grb.measured(fails, {"name": "gemm_f16"}, 1.0) == {
        "name": "gemm_f16", "error": '"addmm_impl_cpu_" not implemented for \'Half\''}
    assert grb.measured(lambda: 2.0, {"name": "gemm_f32"}, 8e6) == {"name": "gemm_f32", "ms": 2.0, "gflops": 4.0}
    calls = []
    ms = grb.Timer(None, "cpu")(lambda: calls.append(1), 3)
    assert len(calls) == 4 and isinstance(ms, float) and ms >= 0  # one warm-up call, then the median of 3


# --- gpu-session.sh alone: the status lines, what is kept, the exit status -------------------------

@pytest.mark.parametrize("check_rc,pool_rc,train_rc,cpu", [(0, 0, 0, False), (3, 0, 0, True), (0, 2, 1, False),
                                                           (0, 0, 1, True)])
def test_session_status_lines(tmp_path, check_rc, pool_rc, train_rc, cpu):
    repo = Repo(tmp_path, real=("gpu-session.sh",), bundle=False)
    teacher = tmp_path / "teacher.pt"
    teacher.write_text("t")
    r = repo.run("gpu-session.sh", "run", *(["--cpu"] if cpu else []), GPU_SESSION_TEACHER=teacher,
                 GPU_SESSION_SECONDS=500, GPU_SESSION_CHECK_SECONDS=222, STUB_CHECK_RC=check_rc,
                 STUB_POOL_RC=pool_rc, STUB_TRAIN_RC=train_rc)
    assert (r.returncode == 0) == (check_rc == 0 and train_rc == 0), r.stdout + r.stderr
    log = open(os.path.join(repo.out, "train", "steps.log")).read()
    assert f"check: exit {check_rc}, pool: exit {pool_rc} (cores 2, overlapped: 0)" in log
    assert f"training: exit {train_rc}" in log
    left = int(re.search(r"training with (\d+) s left", log).group(1))
    assert 470 <= left <= 500
    # each part's last words in the log where it failed, its whole output kept only then
    assert ("pool: last words" in log) == (pool_rc != 0)
    assert ("training: last words" in log) == (train_rc != 0)
    kept = {f for f in ("check.stdout", "pool.stdout", "train.stdout") if os.path.exists(os.path.join(repo.out, f))}
    assert kept == {f for f, rc in (("check.stdout", check_rc), ("pool.stdout", pool_rc),
                                    ("train.stdout", train_rc)) if rc}
    # the check's report.json and steps.log travel in its archive only
    assert sorted(os.listdir(os.path.join(repo.out, "check"))) == ["gpu-check-all.tar.xz", "report.md"]
    assert "check's report.md" in r.stdout and "| variant |" in r.stdout
    # what each callee was given: the check first, then the pool, then the training with what is left
    calls = [line.split(" | ")[0] for line in open(repo.log).read().splitlines()]
    c = " --cpu" if cpu else ""
    assert calls == [f"gpu-check run{' --cpu-coopmat' if cpu else ''}", f"gpu-train pool{c}", f"gpu-train run{c}"]
    check, _, train = [line.split(" | ")[1] for line in open(repo.log).read().splitlines()]
    assert f"OUT={repo.out}/check secs=222 " in check
    assert train == f"OUT={repo.out}/train secs={left} teacher={teacher} work={repo.train_work}"


def test_session_overlaps_on_eight_cores_or_more(tmp_path):
    repo = Repo(tmp_path, real=("gpu-session.sh",), bundle=False)
    teacher = tmp_path / "teacher.pt"
    teacher.write_text("t")
    r = repo.run("gpu-session.sh", "run", GPU_SESSION_TEACHER=teacher, STUB_NPROC=16)
    assert r.returncode == 0, r.stderr
    log = open(os.path.join(repo.out, "train", "steps.log")).read()
    assert "check: exit 0, pool: exit 0 (cores 16, overlapped: 1)" in log
    pinned = sorted(repo.records("taskset "))
    assert pinned == ["0-3 omp=4 bash scripts/gpu/gpu-check.sh run", "4-15 omp= bash scripts/gpu/gpu-train.sh pool"], pinned


# --- gpu-check.sh: the driver, the plan, the steps' limits and the deadline -------------------------

def fake_nvidia(base, *files):
    root = os.path.join(str(base), "nvidia-root")
    for f in files:
        write(os.path.join(root, f), "{}\n" if f.endswith(".json") else "ELF")
    return root


@pytest.mark.parametrize("where", ["given", "manifest", "library", "library64", "none"])
def test_check_finds_the_nvidia_driver(tmp_path, where):
    """VK_DRIVER_FILES first, then the usual manifests; with none, a manifest of our own naming
    libGLX_nvidia.so.0 (the first of the usual library folders that has it); with neither, a
    one-line failure. Every step is skipped here (GPU_CHECK_SECONDS 10): only the driver matters."""
    repo = Repo(tmp_path)
    given = tmp_path / "given_icd.json"
    given.write_text("{}")
    files = {"given": ["usr/lib/x86_64-linux-gnu/libGLX_nvidia.so.0"],
             "manifest": ["etc/vulkan/icd.d/nvidia_icd.json", "usr/lib/x86_64-linux-gnu/libGLX_nvidia.so.0"],
             "library": ["usr/lib/x86_64-linux-gnu/libGLX_nvidia.so.0", "lib/x86_64-linux-gnu/libGLX_nvidia.so.0"],
             "library64": ["usr/local/nvidia/lib64/libGLX_nvidia.so.0", "usr/local/nvidia/lib/libGLX_nvidia.so.0",
                           "usr/lib/x86_64-linux-gnu/libGLX_nvidia.so.0"],
             "none": ["usr/lib/x86_64-linux-gnu/libvulkan.so.1"]}[where]
    nv = fake_nvidia(tmp_path, *files)
    r = repo.run("gpu-check.sh", "run", GPU_CHECK_NVIDIA_ROOT=nv, GPU_CHECK_SECONDS=10,
                 VK_DRIVER_FILES=given if where == "given" else None)
    log = open(os.path.join(repo.check_work, "out", "steps.log")).read()
    own = os.path.join(repo.check_work, "nvidia_icd.json")
    if where == "none":
        assert r.returncode == 1 and "no NVIDIA Vulkan driver manifest and no libGLX_nvidia.so.0 found" in log
        assert repo.records("bin ") == [] and not os.path.exists(own)
        return
    assert r.returncode == 0, r.stderr
    expect = {"given": str(given), "manifest": f"{nv}/etc/vulkan/icd.d/nvidia_icd.json"}.get(where, own)
    (seen,) = repo.records("bin spar-bench --list-devices | ")  # the only program before the skipped steps
    assert f"driver={expect} icd={expect} layers={repo.check_work}/layers " in seen
    lib = {"library": f"{nv}/usr/lib/x86_64-linux-gnu/libGLX_nvidia.so.0",
           "library64": f"{nv}/usr/local/nvidia/lib64/libGLX_nvidia.so.0"}.get(where)
    if lib:
        assert json.load(open(own)) == {"file_format_version": "1.0.1",
                                        "ICD": {"library_path": lib, "api_version": "1.3.0"}}
        assert f"no NVIDIA Vulkan driver manifest found: using {lib}" in log
    else:
        assert not os.path.exists(own)
    # the bundle's loader, its libraries first, then the driver's folders that exist
    dirs = [d for d in ("usr/local/nvidia/lib64", "usr/local/nvidia/lib", "usr/lib/x86_64-linux-gnu",
                        "lib/x86_64-linux-gnu") if os.path.isdir(os.path.join(nv, d))]
    assert repo.records("ld ") == [":".join([f"{repo.check_work}/runtime"] + [f"{nv}/{d}" for d in dirs])]


def test_check_skips_steps_past_its_deadline(tmp_path):
    """GPU_CHECK_SECONDS used up: every step is reported skipped (none runs) but the report,
    and the report says so."""
    repo = Repo(tmp_path)
    r = repo.run("gpu-check.sh", "run", "--cpu", GPU_CHECK_SECONDS=10)
    assert r.returncode == 0, r.stderr
    names = check_steps(coopmat=False, report=False)
    assert steps_rc(repo.check_work) == [(n, "skipped") for n in names] + [("report", "0")]
    log = open(os.path.join(repo.check_work, "out", "steps.log")).read()
    for n in names:
        assert f"{n}: skipped (the run's 10 s are used up)" in log
    assert [x.split(" | ")[0] for x in repo.records("bin ")] == ["spar-bench --list-devices"]
    assert repo.records("timeout ") == ["60"]  # the report alone ran, with its own limit
    assert sorted(os.listdir(repo.out)) == ["gpu-check-all.tar.xz", "report.md", "steps.log"]
    # the real report on what the run left (in this process: PyTorch, which it imports, loads once)
    import gpu_check_report
    out = os.path.join(repo.check_work, "out")
    assert gpu_check_report.main(["gpu_check_report.py", out]) == 0
    steps = json.load(open(os.path.join(out, "report.json")))["steps"]
    assert steps == dict({n: "skipped" for n in names}, report=0)  # (the report's own step, run before)
    md = open(os.path.join(out, "report.md")).read()
    assert "Steps: kernels skipped, selftest skipped, op-goldens skipped, test-test_linear skipped, " in md


@pytest.mark.parametrize("mode", ["--cpu", "--cpu-coopmat"])
def test_check_cpu_runs_every_step(tmp_path, mode):
    """--cpu: lavapipe 22.3 (no test_coopmat), --cpu-coopmat: Debian 13's lavapipe from DIR with
    the GPU's plan for spar-bench and test_coopmat; small shapes, a quarter of each test program.
    A failing test program is reported and the steps after it still run."""
    repo = Repo(tmp_path)
    lvp = tmp_path / "mesa-trixie"
    write(str(lvp / "lvp_icd.json"), "{}")
    coop = mode == "--cpu-coopmat"
    r = repo.run("gpu-check.sh", "run", mode, DIR=lvp, STUB_FAILING_TESTS="test_pool", GPU_CHECK_SECONDS=None)
    assert r.returncode == 0, r.stderr
    tests = OP_TESTS + (["test_coopmat"] if coop else []) + MODEL_TESTS
    names = check_steps(coop)
    assert steps_rc(repo.check_work) == [(n, "1" if n == "test-test_pool" else "0") for n in names]
    runs = {}
    for line in repo.records("bin "):
        cmd, seen = line.split(" | ")
        runs.setdefault(cmd.split()[0], []).append((cmd, dict(kv.split("=", 1) for kv in seen.split())))
    plan = {"kernels": "coopmat", "measure": "1"} if coop else {"kernels": "", "measure": ""}
    model = f"spar-bench --model {repo.check_work}/model.spar --views 4 --targets 4 --precision"
    assert [c for c, s in runs["spar-bench"]] == [
        "spar-bench --list-devices", "spar-bench --list-kernels --json",
        f"spar-bench --selftest --selftest-model-dir {repo.root}/data/selftest",
        "spar-bench --json --repeat 2 --only _f32",
        f"{model} fp32 --repeat 2 --json", f"{model} fp16 --repeat 2 --json", f"{model} fp32 --repeat 2 --json"]
    assert [s["inputs"] for c, s in runs["spar-bench"]] == [""] * 6 + ["texel"]  # the last: texel inputs
    for cmd, seen in runs["spar-bench"][1:]:
        assert {k: seen[k] for k in plan} == plan, cmd
    for t in tests:
        ((cmd, seen),) = runs[t]
        assert cmd == f"{t} --gtest_output=json:{repo.check_work}/out/tests/{t}.json"
        assert seen["kernels"] == ("coopmat" if t == "test_coopmat" else "") and seen["measure"] == "0", t
        assert seen["shards"] == ("/" if t in MODEL_TESTS else "4/0"), t
        assert seen["goldens"] == (f"{repo.check_work}/goldens" if t in MODEL_TESTS else ""), t
        assert seen["op_goldens"] == f"{repo.check_work}/op-goldens", t
    driver = f"{lvp}/lvp_icd.json" if coop else ""
    assert {s["driver"] for c in runs.values() for _, s in c} == {driver}
    extra = [f"{lvp}/root/usr/lib/x86_64-linux-gnu"] if coop else []
    assert set(repo.records("ld ")) == {":".join([f"{repo.check_work}/runtime"] + extra +
                                                 ["/usr/lib/x86_64-linux-gnu", "/lib/x86_64-linux-gnu"])}
    ref = repo.tool_calls("gpu_reference_bench.py")
    w = repo.check_work
    assert ref == [["--ops", "--out", f"{w}/out/reference_ops.json", "--small", "--repeat", "3"],
                   ["--checkpoint", f"{w}/model.pt", "--config", f"{w}/model.json", "--views", "4", "--targets", "4",
                    "--repeat", "2", "--out", f"{w}/out/reference_model.json"]]
    # the steps' limits, as no deadline is near: each its own
    limits = [int(x) for x in repo.records("timeout ")]
    assert limits == [STEP_LIMITS.get(n, 300) for n in names]
    # the archive holds every step's log and JSON
    with tarfile.open(os.path.join(repo.out, "gpu-check-all.tar.xz")) as tar:
        inside = set(tar.getnames())
    assert {f"out/{n}.log" for n in names} | {f"out/tests/{t}.json" for t in tests} | \
        {"out/steps.rc", "out/steps.log", "out/kernels.json", "out/reference_ops.json"} <= inside


# --- pack: the bundle the device machine gets, and the teacher ----------------------------------------

RUNTIME = ["ld-linux-x86-64.so.2", "libc.so.6", "libm.so.6", "libstdc++.so.6", "libgcc_s.so.1", "libvulkan.so.1",
           "libGLdispatch.so.0"]


def pack_inputs(repo, base):
    """A build with every program of the bundle (a real executable: strip and ldd must work on
    it), DIR with Debian 13's files as scripts/portability/coopmat-lavapipe.sh leaves them, a git repository."""
    build, mesa = os.path.join(base, "build"), os.path.join(base, "mesa")
    for b in BINS:
        d = os.path.join(build, "bin" if b == "spar-bench" else "tests")
        os.makedirs(d, exist_ok=True)
        shutil.copy("/bin/true", os.path.join(d, b))
    debug = os.path.join(base, "debug-info")
    write(debug, "x" * 100000)
    subprocess.run(["objcopy", "--add-section", f".debug_stub={debug}", os.path.join(build, "bin", "spar-bench")],
                   check=True)  # something for strip to take away
    lib = os.path.join(mesa, "root", "usr", "lib", "x86_64-linux-gnu")
    for name in [x for x in RUNTIME if x != "libvulkan.so.1"] + ["libVkLayer_khronos_validation.so"]:
        write(os.path.join(lib, name), f"{name} of Debian 13\n")
    write(os.path.join(lib, "libvulkan.so.1.4.309"), "libvulkan.so.1 of Debian 13\n")
    os.symlink("libvulkan.so.1.4.309", os.path.join(lib, "libvulkan.so.1"))
    write(os.path.join(mesa, "root", "usr", "share", "vulkan", "explicit_layer.d", "VkLayer_khronos_validation.json"),
          '{"layer": {"name": "VK_LAYER_KHRONOS_validation", "library_path": "libVkLayer_khronos_validation.so"}}\n')
    write(os.path.join(repo.root, "scripts", "portability", "coopmat-lavapipe.sh"), 'echo "coopmat-lavapipe DIR=$DIR" >> "$STUB_LOG"\n')
    git = ["git", "-C", repo.root, "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(git + ["init", "-q"], check=True)
    subprocess.run(git + ["commit", "-q", "--allow-empty", "-m", "t"], check=True)
    head = subprocess.run(git + ["rev-parse", "HEAD"], check=True, capture_output=True, text=True).stdout.strip()
    return dict(SPAR_BUILD=build, DIR=mesa, TMPDIR=base), head


def test_check_pack_bundles_what_runs_there(tmp_path):
    """gpu-check.sh pack: every program stripped, Debian 13's loader and libraries (links
    followed), the validation layer with a manifest naming it beside itself; the commit; the
    bundle kept out of git. A program not built is a one-line error and no bundle."""
    repo = Repo(tmp_path, bundle=False)
    env, head = pack_inputs(repo, str(tmp_path))
    bench = os.path.join(tmp_path, "build", "bin", "spar-bench")
    os.rename(bench, bench + ".away")
    r = repo.run("gpu-check.sh", "pack", **env)
    assert r.returncode == 1 and r.stderr.strip() == f"gpu-check: spar-bench not built (cmake --build {tmp_path}/build)"
    assert not os.path.exists(os.path.join(repo.root, ".gpucheck", "bundle.tar.xz"))
    os.rename(bench + ".away", bench)
    r = repo.run("gpu-check.sh", "pack", **env)
    assert r.returncode == 0, r.stderr
    assert repo.records("coopmat-lavapipe ") == [f"DIR={tmp_path}/mesa"] * 2
    assert open(os.path.join(repo.root, ".gpucheck", "commit")).read().strip() == head
    assert open(os.path.join(repo.root, ".git", "info", "exclude")).read().count("/.gpucheck/\n") == 1
    with tarfile.open(os.path.join(repo.root, ".gpucheck", "bundle.tar.xz")) as tar:
        members = {m.name: m for m in tar.getmembers() if m.isfile()}
        layers = ["layers/libVkLayer_khronos_validation.so", "layers/VkLayer_khronos_validation.json"]
        assert sorted(members) == sorted([f"bin/{b}" for b in BINS] + [f"runtime/{x}" for x in RUNTIME] + layers)
        assert tar.extractfile("runtime/libvulkan.so.1").read() == b"libvulkan.so.1 of Debian 13\n"
        layer = json.load(tar.extractfile("layers/VkLayer_khronos_validation.json"))
        assert layer["layer"]["library_path"] == "./libVkLayer_khronos_validation.so"
        assert all(members[f"bin/{b}"].mode & 0o111 for b in BINS)
        assert members["bin/spar-bench"].size < os.path.getsize(bench) - 100000  # stripped
    assert "carry .gpucheck and run: bash scripts/gpu/gpu-check.sh run" in r.stdout


def test_session_pack_makes_the_teacher_once(tmp_path):
    """gpu-session.sh pack: the check's bundle (gpu-check.sh pack; its failure stops it), then
    the CPU recipe's teacher (spar-train's defaults, one step, the pool's cache in the build)
    unless .gpucheck has one."""
    repo = Repo(tmp_path, real=("gpu-session.sh",), bundle=False)
    env = dict(SPAR_BUILD=tmp_path / "build", TMPDIR=tmp_path)
    r = repo.run("gpu-session.sh", "pack", STUB_CHECK_RC=1, **env)
    assert r.returncode == 1 and repo.tool_calls("spar-train") == []
    r = repo.run("gpu-session.sh", "pack", **env)
    assert r.returncode == 0, r.stderr
    assert [x.split(" | ")[0] for x in repo.records("gpu-check ")] == ["pack", "pack"]
    (call,) = repo.tool_calls("spar-train")
    assert call[2:] == ["--cache", f"{tmp_path}/build/scene-cache", "--steps", "1", "--save-every", "0", "--no-pack"]
    teacher = os.path.join(repo.root, ".gpucheck", "teacher.pt")
    assert open(teacher).read() == "teacher made by " + " ".join(call)
    assert "teachers: stub text encoder and LSeg" in r.stdout
    assert r.stdout.strip().splitlines()[-1].startswith("gpu-session: carry .gpucheck (")
    assert [f for f in os.listdir(tmp_path) if f.startswith("tmp")] == []  # its scratch removed
    r = repo.run("gpu-session.sh", "pack", **env)
    assert r.returncode == 0 and len(repo.tool_calls("spar-train")) == 1
    assert open(teacher).read() == "teacher made by " + " ".join(call)


# --- gpu-train.sh: pool, variants, minutes ----------------------------------------------------------

def test_train_pool_then_run_reuses_the_pool(tmp_path):
    repo = Repo(tmp_path)
    teacher = tmp_path / "teacher.pt"
    teacher.write_text("teacher")
    r = repo.run("gpu-train.sh", "pool", GPU_TRAIN_SCENES=16)
    assert r.returncode == 0, r.stderr
    r = repo.run("gpu-train.sh", "run", GPU_TRAIN_SCENES=16, GPU_TRAIN_TEACHER=teacher)
    assert r.returncode == 1  # this test's python3 does not write the weights back
    assert repo.records("python3 -c ") == ["ScenePool"]  # rendered once, by `pool`
    assert len(repo.tool_calls("spar-scenes")) == 1
    log = open(os.path.join(repo.out, "steps.log")).read()
    assert re.search(r"scene pool of 16 and 12 validation scenes in \d+ s on 2 cores", log), log
    assert f"teachers from {teacher}" in log  # `run` appended to the pool's log
    assert open(os.path.join(repo.train_work, "teacher", "teacher.pt")).read() == "teacher"
    r = repo.run("gpu-train.sh", "run", GPU_TRAIN_SCENES=32, GPU_TRAIN_TEACHER=teacher)
    assert r.returncode == 1 and f"the pool in {repo.train_work} is not of 32 scenes" in r.stdout
    assert len(repo.tool_calls("spar-train")) == len(VARIANTS)  # from the one `run` that trained


@pytest.mark.parametrize("seconds,minutes", [(100000, (5.5, 5.5)), (60 + 66 * 2, (1.9, 2.0)), (30, (0.2, 0.2))])
def test_train_variants_fit_the_time_left(tmp_path, seconds, minutes):
    """Every GPU variant at once, each fitted to what is left of GPU_TRAIN_SECONDS (60 s kept for
    writing back, 10 % overrun), never above GPU_TRAIN_MINUTES nor under 0.2; a variant that fails
    is named in the log with its last words."""
    repo = Repo(tmp_path)
    teacher = tmp_path / "teacher.pt"
    teacher.write_text("teacher")
    r = repo.run("gpu-train.sh", "run", GPU_TRAIN_SECONDS=seconds, GPU_TRAIN_TEACHER=teacher,
                 STUB_FAILING_VARIANTS="b32-lr1.5e-3")
    assert r.returncode == 1
    log = open(os.path.join(repo.out, "steps.log")).read()
    m = float(re.search(r"training 5 variants for ([\d.]+) min each", log).group(1))
    assert minutes[0] <= m <= minutes[1], m
    assert "variant b32-lr1.5e-3 failed: stub: b32-lr1.5e-3 ran out of memory" in log
    assert "Stub H200, 143771 MiB" in log  # nvidia-smi's line
    calls = {os.path.basename(c[c.index("--out") + 1]): c for c in repo.tool_calls("spar-train")}
    assert sorted(calls) == sorted(VARIANTS)
    w = repo.train_work
    for name, opts in VARIANTS.items():
        assert calls[name] == (["--out", f"{w}/{name}", "--scenes", "2000", "--cache", f"{w}/scene-cache",
                                "--device", "cuda", "--threads", "2", "--no-pack", "--save-every", "0", "--log-every", "25",
                                "--teacher", f"{w}/teacher/teacher.pt", "--steps", "100000", "--minutes", f"{m:.2f}",
                                "--eval-scenes", f"{w}/val", "--eval-every", "250"] + opts.split())
    assert repo.tool_calls("spar-scenes") == [["split", "--split", "test", "--count", "12", "--start", "12",
                                                "--out", f"{w}/val"]]


# --- the whole call: gpu-session.sh run (the GPU path, every callee real but the programs), unpack ---

BEST = "b16-lr1e-3-st192"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    import torch
    base = tmp_path_factory.mktemp("session")
    repo = Repo(base, report=True)
    # the best variant's weights: ~19 MiB in fp16 (two parts, as the shipped model's), values that
    # fp16 holds exactly; every other variant a small checkpoint
    g = torch.Generator().manual_seed(5)
    model = {"decoder.weight": torch.randn(10_000_000, generator=g).half().float(),
             "decoder.bias": torch.randn(7, generator=g).half().float(), "rope.positions": torch.arange(9)}
    big, small = str(base / "big.pt"), str(base / "small.pt")
    torch.save({"model": model, "optimizer": {"state": {1: torch.ones(3)}}, "lr_scheduler": {"last_epoch": 321},
                "param_update_step": 321, "fwdbwd_pass_step": 321}, big)
    torch.save({"model": {"w": torch.ones(2)}, "optimizer": {}, "lr_scheduler": {}, "param_update_step": 1}, small)
    teacher = base / "teacher.pt"
    teacher.write_bytes(b"teacher of the CPU recipe")
    nv = fake_nvidia(base, "usr/lib/x86_64-linux-gnu/libGLX_nvidia.so.0", "usr/local/nvidia/lib/.keep")
    psnr = {"b8-lr6e-4": 18.0, "b16-lr1e-3": 19.0, "b16-lr1e-3-pose": 19.5, "b32-lr1.5e-3": 20.0, BEST: 21.0}
    ckpts = {v: (big if v == BEST else small) for v in VARIANTS}
    run = repo.run("gpu-session.sh", "run", GPU_SESSION_TEACHER=teacher, GPU_CHECK_NVIDIA_ROOT=nv, STUB_NPROC=16,
                   STUB_REAL_WRITEBACK=1, STUB_PSNR=json.dumps(psnr), STUB_CHECKPOINTS=json.dumps(ckpts))
    # kept before `unpack` runs spar-convert again
    run_calls = {"spar-train": repo.tool_calls("spar-train"), "timeout": repo.records("timeout ")}
    back = base / "back"
    unpack = repo.run("gpu-session.sh", "unpack", repo.out, GPU_SESSION_DEST=back)
    return dict(repo=repo, run=run, unpack=unpack, back=str(back), model=model, teacher=teacher, nv=nv,
                run_calls=run_calls, torch=torch)


def test_session_runs_and_unpacks(session):
    assert session["run"].returncode == 0, session["run"].stdout[-3000:] + session["run"].stderr[-3000:]
    assert session["unpack"].returncode == 0, session["unpack"].stdout + session["unpack"].stderr


def test_session_brings_back_what_the_device_tool_can(session):
    out = session["repo"].out
    files = assert_fits_device_tool(out)
    assert files == ["check/gpu-check-all.tar.xz", "check/report.md", "train/runs.tar.gz", "train/steps.log",
                     "train/summary.md", "train/weights.pt.part-00", "train/weights.pt.part-01"]


def test_session_log_says_every_part_ran(session):
    repo = session["repo"]
    log = open(os.path.join(repo.out, "train", "steps.log")).read()
    assert "scene pool of 2000 and 12 validation scenes" in log  # the pool's lines kept
    assert f"teachers from {session['teacher']}" in log
    assert "check: exit 0, pool: exit 0 (cores 16, overlapped: 1)" in log
    assert "training 5 variants for 5.50 min each" in log
    assert "training: exit 0" in log
    assert sorted(repo.records("taskset ")) == ["0-3 omp=4 bash scripts/gpu/gpu-check.sh run",
                                                "4-15 omp= bash scripts/gpu/gpu-train.sh pool"]
    # the check held to GPU_SESSION_CHECK_SECONDS (260): longer steps cut to what is left of it
    limits = [int(x) for x in session["run_calls"]["timeout"]]
    own = [STEP_LIMITS.get(n, 300) for n in check_steps(coopmat=True)]
    assert len(limits) == len(own)
    for x, o in zip(limits, own):
        assert x == o if o < 240 else 240 <= x <= 260, (limits, own)


def test_session_check_used_our_own_driver_manifest(session):
    repo, nv = session["repo"], session["nv"]
    icd = os.path.join(repo.check_work, "nvidia_icd.json")
    assert json.load(open(icd))["ICD"]["library_path"] == f"{nv}/usr/lib/x86_64-linux-gnu/libGLX_nvidia.so.0"
    seen = [line.split(" | ")[1] for line in repo.records("bin ")]
    # the test programs once each, spar-bench 7 times (devices, kernels, selftest, ops, model fp32, fp16
    # and fp32 with texel inputs)
    assert len(seen) == len(BINS) - 1 + 7 and all(f"driver={icd} icd={icd} " in s for s in seen)
    assert set(repo.records("ld ")) == {f"{repo.check_work}/runtime:{nv}/usr/local/nvidia/lib:"
                                        f"{nv}/usr/lib/x86_64-linux-gnu"}


def test_session_unpack_gives_the_report(session):
    """As the rehearsal: every step ran, every test program passed (test_coopmat among them), the
    plan's cooperative matrices, the model timings of both sides, the ops beside PyTorch."""
    back = session["back"]
    md = open(os.path.join(back, "check", "report.md")).read()
    assert md == open(os.path.join(session["repo"].out, "check", "report.md")).read()
    assert md.startswith("# GPU check: Stub GPU")
    r = json.load(open(os.path.join(back, "check", "out", "report.json")))
    assert r["steps"] and all(v == 0 for v in r["steps"].values()), r["steps"]
    assert sorted(t["program"] for t in r["tests"]) == sorted(BINS[1:])
    assert all(t["failures"] == 0 and t["tests"] == 3 for t in r["tests"])
    assert any("gemm_coopmat.comp" in line for line in r["kernels"])
    assert r["selftest"] == "verdict: PASS (29 of 29 checks passed)"
    assert r["model"]["engine_fp32"]["total"]["gpu_ms"] == 12.5 and r["model"]["engine_fp16"]["total"]["gpu_ms"] == 7.5
    assert r["model"]["reference"]["modes"]["fp32"]["total_ms"] == 40.0
    assert [(o["op"], o["engine_ms"], o["torch_ms"]) for o in r["ops"]] == [("gemm_f32", 2.0, 4.0)]


def test_session_weights_come_back_bit_identical(session):
    """The best variant's weights in parts of 15 MiB, put back together by `unpack` into the
    official layout: every float the run had (fp16-exact), the integer tensors as they were."""
    torch, repo, back = session["torch"], session["repo"], os.path.join(session["back"], "train")
    parts = sorted(f for f in os.listdir(os.path.join(repo.out, "train")) if f.startswith("weights.pt.part-"))
    data = b"".join(open(os.path.join(repo.out, "train", p), "rb").read() for p in parts)
    assert data == open(os.path.join(repo.train_work, "weights.pt"), "rb").read()
    assert len(parts) == math.ceil(len(data) / (15 * MIB)) == 2
    assert all(os.path.getsize(os.path.join(repo.out, "train", p)) == 15 * MIB for p in parts[:-1])
    ck = torch.load(os.path.join(back, "checkpoint.pt"))
    assert sorted(ck["model"]) == sorted(session["model"])
    for k, v in session["model"].items():
        assert ck["model"][k].dtype == v.dtype and torch.equal(ck["model"][k], v), k
    assert ck["optimizer"] == {"state": {}, "param_groups": []} and ck["lr_scheduler"] == {"last_epoch": 321}
    assert ck["param_update_step"] == ck["fwdbwd_pass_step"] == 321
    assert not os.path.exists(os.path.join(back, "weights.pt"))


def test_session_unpack_gives_the_model(session):
    repo, back = session["repo"], os.path.join(session["back"], "train")
    assert open(os.path.join(back, "best")).read() == BEST
    assert json.load(open(os.path.join(back, "config.json"))) == {"variant": BEST}
    assert open(os.path.join(back, "train_log.txt")).read() == f"{BEST}: trained\n"
    assert open(os.path.join(back, "model.spar")).read() == "spar-convert output\n"
    convert = repo.tool_calls("spar-convert")[-1]
    assert convert == ["-q", f"{back}/checkpoint.pt", "--config", f"{back}/config.json", "--fp16",
                       "--bpe", "text/data/clip/bpe_simple_vocab_16e6.txt.gz", "-o", f"{back}/model.spar"]
    summary = open(os.path.join(back, "summary.md")).read()
    assert summary.splitlines()[-1] == f"best on the validation scenes: {BEST}"
    assert "| b16-lr1e-3-st192 | 10 | 1.0 | 20.00 | 12.00 | n/a | 0.250 / 0.500 |" in summary
    # every variant's log, curve and configuration, and its output, in runs.tar.gz
    with tarfile.open(os.path.join(repo.out, "train", "runs.tar.gz")) as tar:
        inside = {n.lstrip("./") for n in tar.getnames()}
    assert inside == {"best"} | {f"{v}.stdout" for v in VARIANTS} | \
        {f"{v}/{f}" for v in VARIANTS for f in ("train_log.txt", "curve.jsonl", "config.json")}
    # the training was given the session's teacher, and the variants what was left of the 560 s
    assert open(os.path.join(repo.train_work, "teacher", "teacher.pt"), "rb").read() == session["teacher"].read_bytes()
    assert len(session["run_calls"]["spar-train"]) == len(VARIANTS)
