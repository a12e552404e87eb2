// fp16 weights (SparPipelineOptions::weightType = F16, or a `spar-convert --fp16` pack) through
// the whole photometric pipeline on the tiny model, against the PyTorch reference's float64
// goldens (fixture spar_goldens), stage by stage (tests/pipeline_check.*):
//  - every stage within the fp16 thresholds (measured, fp16WeightThresholds in pipeline_check.cpp), motion masks identical
//    except near the threshold;
//  - a --fp16 pack (made here from the fixture's checkpoint) and F16 at upload from the F32
//    file load the same weights (up to one fp16 step where the converter folded BatchNorm) and
//    give the same pixels and motion maps to 1e-6;
//  - the --fp16 rule of WeightSet::isMatrix is the converter's (every tensor of the pack);
//  - a matrix value beyond fp16's range refuses F16 at upload, naming the tensor.
#include <gtest/gtest.h>

#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "engine/half.h"
#include "model/memory_estimate.h"
#include "model/packed_model.h"
#include "model/quantized_matrices.h"
#include "model/stages/stage_list.h"
#include "pipeline_check.h"
#include "test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

// P(dynamic) moves by at most 8.2e-7 with fp16 weights (measured, above): the fp32 tie band
// (a reference probability within kMaskTieBand = 1e-4 of the threshold may land on either side)
// holds (measured: no mask pixel differs, and none is that close).
CaseOptions fp16Case(CaseOptions o) {
  o.weightType = DType::F16;
  o.thresholds = fp16WeightThresholds();
  return o;
}

const fs::path& scratch() { return scratchDir("spar_precision"); }

// The fixture's checkpoint packed with --fp16 (tiny16.spar, made in the spar_goldens fixture).
std::string fp16Pack() { return goldenPath("tiny16.spar"); }

class SparPrecisionTest : public EngineTest {};

TEST_F(SparPrecisionTest, Fp16WeightsInterleaved) { runGoldenCase(eng(), "interleaved", fp16Case({})); }
TEST_F(SparPrecisionTest, Fp16WeightsOddTargets) { runGoldenCase(eng(), "odd_targets", fp16Case({})); }
TEST_F(SparPrecisionTest, Fp16WeightsAssumeStatic) {
  runGoldenCase(eng(), "static", fp16Case({.assumeStatic = true}));
}
TEST_F(SparPrecisionTest, Fp16WeightsPathCameras) {
  runGoldenCase(eng(), "path", fp16Case({.pathCameras = true}));
}
// The --fp16 pack read as stored (weightType F32: its matrices are F16 on the device).
TEST_F(SparPrecisionTest, Fp16PackInterleaved) {
  CaseOptions o = fp16Case({.model = fp16Pack()});
  o.weightType = DType::F32;
  runGoldenCase(eng(), "interleaved", o);
}

// What the pack stores as F16 is exactly what WeightSet::isMatrix calls a matrix.
TEST_F(SparPrecisionTest, MatrixRuleIsTheConverters) {
  const PackedModel pack = PackedModel::open(fp16Pack());
  size_t matrices = 0;
  for (const std::string& name : pack.names()) {
    const PackedTensorInfo& info = pack.info(name);
    if (info.dtype != FileDType::F32 && info.dtype != FileDType::F16) continue;
    const bool half = info.dtype == FileDType::F16;
    EXPECT_EQ(half, WeightSet::isMatrix(name, info.shape)) << name;
    matrices += half;
  }
  EXPECT_GT(matrices, 50u);
}

struct Outputs {
  std::vector<float> rgb, motionInput, motionTarget;
  std::map<std::string, std::vector<float>> weights;  // every uploaded weight, by name + dtype
  uint64_t bytes = 0;
};

// keepWeights: every uploaded weight downloaded into Outputs::weights (f32 / f16 ones).
Outputs runInterleaved(Engine& engine, const std::string& modelPath, DType weightType, bool keepWeights = true) {
  const GoldenCase g("interleaved");
  const PackedModel model = PackedModel::open(modelPath);
  SparPipeline pipe(engine, model, {.profile = false, .weightType = weightType});
  SparRequest req;
  req.images = prepareFrames(g, pipe.config().imageHeight, pipe.config().imageWidth);
  req.plan = {int64_t(g.files().size()), g.inputs(), g.targets()};
  req.targetMotion = true;
  Outputs r;
  const SparEncoded& e = pipe.encode(req);
  r.motionInput = e.motionInput;
  r.motionTarget = e.motionTarget;
  r.rgb = pipe.renderTargets();
  r.bytes = pipe.weightBytesLoaded();
  const WeightSet& w = pipe.weights();
  if (keepWeights)
    for (const auto& [name, dtype] : w.loaded())
    r.weights[name + ":" + dtypeName(dtype)] = engine.download(w.loadedTensor(name, dtype));
  return r;
}

// The memory estimate's weights (model/memory_estimate.h) for runInterleaved's request: what the
// run loads, byte for byte (its rule is WeightSet's, and the tensors stages read as f32).
uint64_t estimatedWeightBytes(const std::string& modelPath, DType weightType) {
  const PackedModel model = PackedModel::open(modelPath);
  const SparConfig c = SparConfig::fromJson(model.config(), modelPath);
  const GoldenCase g("interleaved");
  RequestShape q;
  q.views = int64_t(g.files().size());
  q.inputs = int64_t(g.inputs().size());
  q.targets = q.renderChunk = int64_t(g.targets().size());
  q.height = c.imageHeight;
  q.width = c.imageWidth;
  q.targetMotion = true;
  q.matrixType = weightType;
  return estimateMemory(model, c, q).weightBytes;
}

// The same on the semantic model under fp16 (LSeg's projections read as linear layers in f16,
// its readouts and convolutions in f32).
TEST_F(SparPrecisionTest, EstimatedWeightsAreTheLoadedOnesOnTheSemanticModel) {
  const std::string model = semanticGoldenPath("tiny_semantic.spar");
  EXPECT_EQ(runInterleaved(eng(), model, DType::F16, false).bytes, estimatedWeightBytes(model, DType::F16));
}

// ---- The stage list (model/stages/stage_list.h) the pipeline runs and the estimate adds up

// A request's shape at a model's own size, 3 inputs and 2 targets.
RequestShape shapeAt(const SparConfig& c) {
  RequestShape q;
  q.views = 5;
  q.inputs = 3;
  q.targets = q.renderChunk = 2;
  q.height = c.imageHeight;
  q.width = c.imageWidth;
  return q;
}

// Every tensor of a model belongs to a module some stage loads: the estimate counts the weights
// of the stages a request runs, so a module no stage claims would go uncounted (and a new stage
// that forgets to declare its weights fails here on the first model that has them).
TEST(SparStageList, EveryTensorBelongsToAStage) {
  for (const std::string& path : {goldenPath("tiny_sam2.spar"), semanticGoldenPath("tiny_semantic.spar"),
                                   std::string(SPAR_SOURCE_DIR) + "/data/spar_rooms.spar"}) {
    const PackedModel model = PackedModel::open(path);
    const SparConfig c = SparConfig::fromJson(model.config(), path);
    const RequestShape q = shapeAt(c);
    const std::vector<std::string> modules = stageModules({model, c, q});
    for (const std::string& name : model.names())
      EXPECT_TRUE(std::count(modules.begin(), modules.end(), name.substr(0, name.find('.')))) << path << ": " << name;
  }
}

// What a request does not need is not in its list: no motion stages for a static scene, no
// SAM2.1 unless refining, LSeg only without its features given, the label phases only with
// prompts; and a semantic model's request runs its semantic stages.
TEST(SparStageList, ARequestRunsOnlyWhatItNeeds) {
  const std::string path = semanticGoldenPath("tiny_semantic.spar");
  const PackedModel model = PackedModel::open(path);
  const SparConfig c = SparConfig::fromJson(model.config(), path);
  auto names = [&](const RequestShape& q) {
    std::string out;
    for (const auto& stage : pipelineStages({model, c, q})) out += std::string(out.empty() ? "" : " ") + stage->name();
    return out;
  };
  RequestShape q = shapeAt(c);
  EXPECT_EQ(names(q), "image_tokens pose_estimator rays dino_v3 cv_drp gating lseg semantic_tokens scene_encoder renderer");
  q.assumeStatic = true;
  EXPECT_EQ(names(q), "image_tokens pose_estimator rays gating lseg semantic_tokens scene_encoder renderer");
  q.lsegGiven = true;
  q.labels = true;
  q.prompts = 2;
  EXPECT_EQ(names(q), "image_tokens pose_estimator rays gating semantic_tokens scene_encoder renderer text_encoder labels");
  q = shapeAt(c);
  q.refine = true;  // this model has no SAM2.1 weights: its list cannot refine
  EXPECT_EQ(names(q).find("sam2_refine"), std::string::npos);
  const PackedModel sam2 = PackedModel::open(goldenPath("tiny_sam2.spar"));
  const SparConfig c2 = SparConfig::fromJson(sam2.config(), sam2.path());
  RequestShape r = shapeAt(c2);
  r.refine = true;
  std::string refined;
  for (const auto& stage : pipelineStages({sam2, c2, r})) refined += std::string(refined.empty() ? "" : " ") + stage->name();
  EXPECT_EQ(refined, "image_tokens pose_estimator rays dino_v3 cv_drp sam2_refine gating scene_encoder renderer");
}

// ---- Quantized matrices (converter/FORMAT.md, "Quantized matrices")

std::string quantizedPack(DType q) { return goldenPath(q == DType::Q8 ? "tiny_q8.spar" : "tiny_q4.spar"); }

// What `spar-convert --weights q8` quantizes is exactly what isQuantizedMatrix names (the rule
// the engine applies at upload to an fp32 file); every other tensor is stored as in the fp32
// file. On the tiny model and on the semantic one (LSeg's ViT, CLIP's tower and token embedding).
TEST_F(SparPrecisionTest, QuantizedRuleIsTheConverters) {
  for (const auto& [fp32Path, q8Path] : {std::pair{tinyModelPath(), quantizedPack(DType::Q8)},
                                         std::pair{semanticGoldenPath("tiny_semantic.spar"),
                                                   semanticGoldenPath("tiny_semantic_q8.spar")}}) {
    SCOPED_TRACE(q8Path);
    const PackedModel f32 = PackedModel::open(fp32Path), pack = PackedModel::open(q8Path);
    EXPECT_EQ(pack.metadata().at("format_version"), PackedModel::kQuantFormatVersion);
    size_t quantized = 0, backbones = 0;
    for (const std::string& name : f32.names()) {
      const PackedTensorInfo& info = f32.info(name);
      ASSERT_TRUE(pack.has(name)) << name;
      const bool q = pack.info(name).quantBits == 8;
      EXPECT_EQ(q, isQuantizedMatrix(name, info.shape)) << name;
      EXPECT_EQ(pack.info(name).shape, info.shape) << name;
      if (!q) {
        EXPECT_EQ(pack.info(name).dtype, info.dtype) << name;
      }
      quantized += q;
      backbones += q && (name.rfind("clip.", 0) == 0 || name.rfind("lseg.", 0) == 0);
    }
    EXPECT_GT(quantized, 30u);
    if (f32.has("clip.token_embedding.weight")) {
      EXPECT_GT(backbones, 20u);
    }
  }
}

// Q8 / Q4 at upload from the fp32 file == the q8 / q4 pack read as stored: the same codes and
// scales (both quantize the same float32 values by the same rule), so the same outputs, bit for
// bit, and the same bytes on the device.
TEST_F(SparPrecisionTest, QuantizedPackEqualsUpload) {
  for (DType q : {DType::Q8, DType::Q4}) {
    SCOPED_TRACE(dtypeName(q));
    const Outputs pack = runInterleaved(eng(), quantizedPack(q), DType::F32, false);
    const Outputs upload = runInterleaved(eng(), tinyModelPath(), q, false);
    EXPECT_EQ(pack.rgb, upload.rgb);
    EXPECT_EQ(pack.motionInput, upload.motionInput);
    EXPECT_EQ(pack.motionTarget, upload.motionTarget);
    EXPECT_EQ(pack.bytes, upload.bytes);
    EXPECT_EQ(upload.bytes, estimatedWeightBytes(tinyModelPath(), q));
    EXPECT_EQ(pack.bytes, estimatedWeightBytes(quantizedPack(q), DType::F32));
  }
}

// F16 at upload from the F32 file == the --fp16 pack: the same weights on the device, bit for
// bit (both round the same float32 values to nearest even), except the tensors the converter
// folded in float64 (BatchNorm into the CV-DRP decoder convs): the pack rounds those once from
// float64, the F32 file rounded them to float32 first, so a few elements sit one fp16 step
// apart (measured: 23 elements). Outputs therefore agree far below the fp16 error itself
// (measured: rgb max abs 1.2e-7 and motion 6e-8 between the two, against 4.3e-5 between f16
// and f32 weights).
void expectPackEqualsUpload(const Outputs& pack, const Outputs& upload, const Outputs& fp32) {
  const nlohmann::json folded =
      nlohmann::json::parse(PackedModel::open(fp16Pack()).metadata().at("conversion")).at("folded");
  ASSERT_EQ(pack.weights.size(), upload.weights.size());
  size_t differing = 0;
  for (const auto& [key, values] : pack.weights) {
    ASSERT_TRUE(upload.weights.count(key)) << key << " not loaded the same way";
    const std::vector<float>& other = upload.weights.at(key);
    ASSERT_EQ(values.size(), other.size()) << key;
    if (values == other) continue;
    const std::string name = key.substr(0, key.rfind(':'));
    EXPECT_TRUE(folded.contains(name)) << key << " differs but was not folded by the converter";
    for (size_t i = 0; i < values.size(); ++i) {
      if (values[i] == other[i]) continue;
      ++differing;
      // Adjacent fp16 values: their half encodings differ by one.
      const int step = std::abs(int(floatToHalf(values[i])) - int(floatToHalf(other[i])));
      EXPECT_EQ(step, 1) << key << "[" << i << "]: " << values[i] << " vs " << other[i];
    }
  }
  EXPECT_EQ(pack.bytes, upload.bytes);
  EXPECT_LT(upload.bytes, fp32.bytes);
  const ErrorStats rgb = compare(pack.rgb, toDouble(upload.rgb));
  const ErrorStats motion = compare(pack.motionInput, toDouble(upload.motionInput));
  const ErrorStats toFp32 = compare(upload.rgb, toDouble(fp32.rgb));
  std::printf("  weight bytes: fp32 %llu, fp16 pack %llu, f16 at upload %llu; %zu folded weight elements one fp16 "
              "step apart\n  pack vs upload: rgb max abs %.3e, motion max abs %.3e; f16 vs f32 weights: rgb max abs "
              "%.3e\n",
              (unsigned long long)fp32.bytes, (unsigned long long)pack.bytes, (unsigned long long)upload.bytes,
              differing, rgb.maxAbs, motion.maxAbs, toFp32.maxAbs);
  EXPECT_LE(rgb.maxAbs, 1e-6);
  EXPECT_LE(motion.maxAbs, 1e-6);
  EXPECT_LE(compare(pack.motionTarget, toDouble(upload.motionTarget)).maxAbs, 1e-6);
  EXPECT_GT(toFp32.maxAbs, 10 * rgb.maxAbs);  // the option does change the weights
}

// The --fp16 pack run at fp32: its F16 matrices are widened at upload (an fp32 run then uses
// only the f32 kernels: on lavapipe every extra kernel variant costs seconds of JIT), so it
// loads what an F32 file loads, with the fp16 pack's values, and computes what the f16 run does
// up to the f32 kernels' own rounding.
void expectPackWidenedAtFp32(const Outputs& wide, const Outputs& half, const Outputs& fp32) {
  EXPECT_EQ(wide.bytes, fp32.bytes);
  EXPECT_LT(half.bytes, wide.bytes);
  size_t widened = 0;
  for (const auto& [key, values] : wide.weights) {
    const std::string name = key.substr(0, key.rfind(':'));
    if (!half.weights.count(name + ":f16")) continue;
    EXPECT_EQ(key.substr(key.rfind(':') + 1), "f32") << key;
    ++widened;
    const std::vector<float>& h = half.weights.at(name + ":f16");
    EXPECT_EQ(values, h) << name << ": widened values differ from the f16 ones";
  }
  EXPECT_GT(widened, 10u);
  const ErrorStats rgb = compare(wide.rgb, toDouble(half.rgb));
  std::printf("  fp16 pack at fp32 vs at fp16: %zu matrices widened, rgb max abs %.3e\n", widened, rgb.maxAbs);
  EXPECT_LE(rgb.maxAbs, 1e-5);
}

// One test for both comparisons (four runs in one process, where two tests ran six in two:
// the f16 and f32 kernels are compiled once).
TEST_F(SparPrecisionTest, Fp16PackEqualsF16AtUploadAndWidensAtFp32) {
  const Outputs pack = runInterleaved(eng(), fp16Pack(), DType::F16);
  const Outputs upload = runInterleaved(eng(), tinyModelPath(), DType::F16);
  const Outputs fp32 = runInterleaved(eng(), tinyModelPath(), DType::F32);
  const Outputs wide = runInterleaved(eng(), fp16Pack(), DType::F32);
  expectPackEqualsUpload(pack, upload, fp32);
  expectPackWidenedAtFp32(wide, pack, fp32);
  EXPECT_EQ(upload.bytes, estimatedWeightBytes(tinyModelPath(), DType::F16));
  EXPECT_EQ(pack.bytes, estimatedWeightBytes(fp16Pack(), DType::F16));
  EXPECT_EQ(fp32.bytes, estimatedWeightBytes(tinyModelPath(), DType::F32));
  EXPECT_EQ(wide.bytes, estimatedWeightBytes(fp16Pack(), DType::F32));
}

// A copy of the tiny F32 file with one element of `name` set to `value` (the data area starts
// after the 8-byte header length and the JSON header).
std::string withValue(const std::string& name, float value) {
  const std::string out = (scratch() / "overflow.spar").string();
  fs::copy_file(tinyModelPath(), out, fs::copy_options::overwrite_existing);
  std::fstream f(out, std::ios::in | std::ios::out | std::ios::binary);
  uint64_t headerBytes = 0;
  f.read(reinterpret_cast<char*>(&headerBytes), 8);
  std::string header(headerBytes, ' ');
  f.read(header.data(), std::streamsize(headerBytes));
  const auto offsets = nlohmann::json::parse(header).at(name).at("data_offsets");
  f.seekp(std::streamoff(8 + headerBytes + offsets[0].get<uint64_t>()));
  f.write(reinterpret_cast<const char*>(&value), 4);
  return out;
}

// spar-convert --fp16 refuses a value fp16 cannot hold; F16 at upload does the same (rather
// than saturating it silently), naming the tensor; F32 weights still load it.
TEST_F(SparPrecisionTest, Fp16OverflowRefused) {
  const std::string name = "image_token_decoder.1.weight";
  const PackedModel model = PackedModel::open(withValue(name, 70000.0f));
  const Shape shape = model.info(name).shape;
  WeightSet half(eng(), model, DType::F16);
  try {
    half.require(name, shape);
    ADD_FAILURE() << "no error for 70000 in an f16 matrix";
  } catch (const Error& e) {
    const std::string msg = e.what();
    std::printf("  %s\n", msg.c_str());
    EXPECT_NE(msg.find(name), std::string::npos) << msg;
    EXPECT_NE(msg.find("float16"), std::string::npos) << msg;
  }
  EXPECT_THROW(half.require(name, shape, DType::F32), Error);
  WeightSet full(eng(), model, DType::F32);
  EXPECT_EQ(eng().download(full.require(name, shape))[0], 70000.0f);
}

}  // namespace
}  // namespace spar::test
