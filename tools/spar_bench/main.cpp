// spar-bench: per op, GPU time, GFLOPS (or GB/s) and NMSE against a float64 CPU
// reference, for every precision the engine offers, and beside them what the first use of
// the op's kernels cost: pipeline creation and the driver's build at the first dispatch
// (compile time, kept apart from run time). --json prints one JSON object. --model M.spar times
// the whole SPAR pipeline instead, stage by stage, on synthetic inputs (tools/spar_bench/bench_model.h).
// --peer times every case's op on the CPU with numpy / PyTorch in the same run and gives the
// engine's speed as a multiple of it (tools/spar_bench/bench_peer.h).
#include "tools/common/selftest_command.h"
#include <CLI/CLI.hpp>
#include <algorithm>
#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>

#include "spar/context.h"
#include "spar/error.h"
#include "spar/precision.h"
#include "tools/spar_bench/bench_model.h"
#include "tools/spar_bench/op_bench.h"

int main(int argc, char** argv) {
  CLI::App app{"spar-bench: time, throughput and error of the engine's ops"};
  std::string device, only;
  bool json = false, listDevices = false, listKernels = false, large = false;
  int repeats = 5;
  app.add_option("--device", device, "device index or name part (default: SPAR_DEVICE, else the first GPU)");
  app.add_option("--only", only, "run the cases whose name contains this (no other case's inputs are made)");
  app.add_option("--repeat", repeats, "timed runs per case (the median is reported)")->check(CLI::Range(1, 1000));
  app.add_flag("--json", json, "print one JSON object instead of a table");
  app.add_flag("--list-devices", listDevices, "list Vulkan devices and exit");
  app.add_flag("--list-kernels", listKernels,
               "say which kernel family and tiles each op uses on the device, and why, and exit (on a GPU "
               "this may first measure the GEMM tiles; kept in kernel-choice.json beside the pipeline cache)");
  app.add_flag("--large", large, "also the 4096x4096x4096 GEMMs (default on GPUs)");
  bool peer = false;
  app.add_flag("--peer", peer,
               "then time each case's op on this machine's CPU cores, in the same run: numpy (OpenBLAS) for GEMMs "
               "and attention, PyTorch for convolutions and row ops, float32, with OPENBLAS_CORETYPE and "
               "OPENBLAS_L2_SIZE removed from its environment (scripts/compare/bench_peer.py); prints the "
               "engine's speed as a multiple of it");
  bool selftest = false;
  app.add_flag("--selftest", selftest,
               "run `spar selftest` (the device, limits, plan and op checks against float64, with the validation "
               "layer where installed) and exit 0 only if it passed: the same code, in the program the GPU "
               "check's bundle carries (it needs no image library)");
  std::string selftestModel;
  app.add_option("--selftest-model-dir", selftestModel, "with --selftest: the self-test model's directory")
      ->needs(app.get_option("--selftest"));
  spar::bench::ModelBenchArgs m;
  std::string size;
  auto* modelOpt = app.add_option("--model", m.model,
                                  "time the whole pipeline of this packed model, stage by stage, on synthetic "
                                  "inputs (no image files) instead of the ops");
  app.add_option("--views", m.views, "with --model: input views (default 4)")->needs(modelOpt);
  app.add_option("--targets", m.targets, "with --model: target views rendered (default 4)")->needs(modelOpt);
  app.add_option("--size", size, "with --model: HxW (default: the model's size)")->needs(modelOpt);
  app.add_option("--precision", m.precision, "with --model: fp32, fp16, q8 or q4 weight matrices")
      ->check(CLI::IsMember(spar::precisionNames()))
      ->needs(modelOpt);
  app.add_flag("--assume-static", m.assumeStatic, "with --model: no DINOv3 / CV-DRP")->needs(modelOpt);
  app.add_flag("--semantic", m.semantic, "with --model: render semantic features too")->needs(modelOpt);
  CLI11_PARSE(app, argc, argv);
  if (peer && !m.model.empty()) {
    std::cerr << "spar-bench: --peer times the op cases; with --model use scripts/compare/compare_onnx.py\n";
    return 2;
  }

  try {
    if (listDevices) {
      for (const auto& d : spar::Context::listDevices()) std::cout << d << "\n";
      return 0;
    }
    if (selftest) return spar::cli::runSelftest({device, json, selftestModel}) ? 0 : 1;
    spar::EngineOptions options;
    options.device = device;
    options.verbose = !json;
    options = spar::EngineOptions::fromEnvironment(options);
    if (options.pipelineCacheFile.empty()) options.pipelineCacheFile = spar::EngineOptions::defaultPipelineCacheFile();
    if (listKernels) {
      spar::Context context(options);
      const auto lines = context.kernelPlan();
      if (json) std::cout << nlohmann::json{{"device", context.deviceName()}, {"kernels", lines}}.dump(2) << "\n";
      else
        for (const auto& l : lines) std::cout << l << "\n";
      return 0;
    }
    if (!m.model.empty()) {
      if (!size.empty()) {
        long long hh = 0, ww = 0;
        char x = 0, extra = 0;
        if (std::sscanf(size.c_str(), "%lld%c%lld%c", &hh, &x, &ww, &extra) != 3 || x != 'x' || hh <= 0 || ww <= 0)
          throw spar::Error("--size must be HxW, got '" + size + "'");
        m.height = hh;
        m.width = ww;
      }
      m.repeats = repeats;
      const auto doc = spar::bench::benchModel(options, m);
      if (json) std::cout << doc.dump(2) << "\n";
      else spar::bench::printModelBench(doc);
      return 0;
    }
    const nlohmann::json report = spar::bench::runOpBench(options, {only, large, repeats, peer, json});
    if (json) std::cout << report.dump(2) << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "spar-bench: " << e.what() << "\n";
    return 1;
  }
}
