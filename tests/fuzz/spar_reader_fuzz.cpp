// Fuzz target of the `.spar` reader: PackedModel's header checks (through fromBytes, the same
// code open() runs on a mapping), SparConfig::fromJson on the config it accepts,
// Sam2Config::fromJson on a SAM2.1 variant's metadata (spar-convert --sam2), then every
// tensor it lists (info, every data byte, checkFinite, floats). A refusal is a spar::Error and
// is the expected outcome of most inputs; anything else (another exception, a crash, a
// sanitizer report, a broken invariant below) is a finding.
//
// Built two ways (tests/fuzz/CMakeLists.txt): with clang and -DSPAR_FUZZ=ON as a libFuzzer
// target, or with any compiler linked to mutation_runner.cpp (the CTest entry).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <vector>

#include "spar/error.h"
#include "model/packed_model.h"
#include "model/sam2_config.h"
#include "model/spar_config.h"

namespace {

volatile unsigned gSink;  // what touchTensors() read, kept so the reads are not optimized away

// A broken promise of the reader: report it as a crash (libFuzzer and the runner keep the input).
void require(bool ok, const char* what) {
  if (ok) return;
  std::fprintf(stderr, "spar_reader_fuzz: invariant broken: %s\n", what);
  std::abort();
}

void checkConfig(const spar::SparConfig& c) {
  // The engine divides by these and sizes buffers from them: an accepted config keeps them sane.
  require(c.d > 0 && c.dHead > 0 && c.d % c.dHead == 0, "d / d_head");
  require(c.cvDrpHeads > 0 && c.d % c.cvDrpHeads == 0, "cv_drp_n_heads");
  require(c.dino.numHeads > 0 && c.dino.embedDim % c.dino.numHeads == 0, "dino heads");
  require(c.tokensPerView() > 0, "tokens per view");
  require(std::isfinite(c.maskThreshold) && std::isfinite(c.semanticLossWeight), "finite scalars");
  require(std::isfinite(c.dino.ffnRatio) && std::isfinite(c.dino.ropeBase) && std::isfinite(c.dino.lnEps),
          "finite dino scalars");
  for (int i = 0; i < 3; ++i)
    require(std::isfinite(c.dino.mean[i]) && std::isfinite(c.dino.std[i]) && c.dino.std[i] > 0, "dino mean / std");
}

void checkSam2(const spar::Sam2Config& c) {
  // The refinement sizes its kernels and buffers from the block schedule.
  const std::vector<spar::Sam2BlockSpec> blocks = c.blocks();
  require(!blocks.empty() && c.stageEnds().size() == 4, "four stages of blocks");
  for (const spar::Sam2BlockSpec& b : blocks)
    require(b.dim > 0 && b.dimOut > 0 && b.heads > 0 && b.window >= 0 && b.dimOut % b.heads == 0 &&
                b.window <= c.tokenSide(),
            "SAM2 block widths, heads and windows");
}

void touchTensors(const spar::PackedModel& m) {
  unsigned sum = 0;
  for (const auto& name : m.names()) {
    const auto& info = m.info(name);  // a listed name must be found
    const auto bytes = m.data(name);
    require(info.begin <= info.end && bytes.size() == info.bytes(), "data span matches info");
    // (a quantized matrix's shape is the matrix's, its bytes its codes': bits / 8 a value)
    require(info.quantBits ? info.bytes() * 8 == static_cast<uint64_t>(info.numel()) * uint64_t(info.quantBits)
                           : info.bytes() == static_cast<uint64_t>(info.numel()) * spar::fileDTypeSize(info.dtype),
            "byte count matches dtype and shape");
    require(8 + info.end <= m.fileBytes(), "tensor inside the file");
    for (uint8_t b : bytes) sum += b;  // every byte read: out-of-bounds shows under ASan
    try {
      m.checkFinite(name);
      if (info.dtype == spar::FileDType::F32 || info.dtype == spar::FileDType::F16 || info.quantBits) {
        const std::vector<float> v = m.floats(name);
        require(v.size() == static_cast<size_t>(info.numel()), "floats() size");
        for (float x : v) require(std::isfinite(x), "floats() after checkFinite are finite");
      }
    } catch (const spar::Error&) {
    }
    try {
      (void)m.naturalDType(name);
    } catch (const spar::Error&) {
    }
  }
  gSink = sum;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::optional<spar::PackedModel> model;
  try {
    model.emplace(spar::PackedModel::fromBytes(std::vector<uint8_t>(data, data + size), "fuzz.spar"));
  } catch (const spar::Error&) {
    return 0;
  }
  require(model->config().is_object() && model->components().is_object(), "config and components objects");
  try {
    checkConfig(spar::SparConfig::fromJson(model->config(), model->path()));
  } catch (const spar::Error&) {
  }
  if (const auto sam2 = model->metadata().find("sam2_config"); sam2 != model->metadata().end()) {
    try {
      checkSam2(spar::Sam2Config::fromJson(sam2->second));
    } catch (const spar::Error&) {
    }
  }
  touchTensors(*model);
  return 0;
}
