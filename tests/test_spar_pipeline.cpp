// The whole photometric pipeline (model/spar_pipeline.*) on the tiny model against the PyTorch
// reference's float64 goldens (tests/python/make_spar_goldens.py), stage by stage: every stage's
// output the pipeline keeps under its golden name is compared with an NMSE threshold of its own.
// The chain is compared as it runs (each stage fed by the engine's previous stages), so the
// thresholds bound the accumulated fp32 error against float64.
#include <cmath>
#include <map>

#include "golden_support.h"
#include "model/image_prep.h"
#include "model/packed_model.h"
#include "model/spar_pipeline.h"
#include "test_support.h"

namespace spar::test {
namespace {

struct StageCheck {
  const char* name;
  double maxNmse;
};

// Thresholds from measurement (fp32 engine vs float64 reference, tiny perturbed model), with
// about 100x margin; the largest errors come from the transformer stacks.
const std::vector<StageCheck> kEncodeChecks = {
    {"img_tokens_raw", 1e-11}, {"pe_code", 1e-13},       {"img_tokens", 1e-11},   {"cam_tokens_in", 1e-11},
    {"pose_encoder_out", 1e-10}, {"cam_tokens", 1e-10}, {"c2w", 1e-10},          {"fxfycxcy", 1e-10},
    {"plucker", 1e-10},          {"ray_tokens", 1e-10}, {"fused_tokens", 1e-10}, {"gated_tokens", 1e-10},
    {"scene_encoder_in", 1e-10}, {"scene_encoder_out", 1e-10}, {"scene_tokens", 1e-10},
};
const std::vector<StageCheck> kRenderChecks = {
    {"render_c2w", 1e-10},  {"render_fxfycxcy", 1e-10}, {"render_plucker", 1e-10}, {"rgb_queries", 1e-10},
    {"decoder_in", 1e-10},  {"decoder_out", 1e-10},     {"rgb_tokens", 1e-10},     {"rgb", 1e-10},
};

std::vector<float> prepareFrames(const GoldenCase& g, int64_t h, int64_t w) {
  std::vector<float> all;
  for (const std::string& f : g.files()) {
    std::vector<float> one = loadPreparedImage(f, int(h), int(w));
    all.insert(all.end(), one.begin(), one.end());
  }
  return all;
}

void expectStage(Engine& engine, const SparPipeline& pipe, const GoldenCase& g, const StageCheck& check) {
  SCOPED_TRACE(check.name);
  ASSERT_TRUE(g.has(check.name)) << "no golden " << check.name;
  const std::vector<double> want = g.doubles(check.name);
  const std::vector<float> got = engine.download(pipe.intermediate(check.name));
  ASSERT_EQ(got.size(), want.size()) << check.name;
  const ErrorStats e = compare(got, want);
  std::printf("  %-20s NMSE %.3e  max abs %.3e\n", check.name, e.nmse, e.maxAbs);
  EXPECT_EQ(e.nonFinite, 0u);
  EXPECT_LE(e.nmse, check.maxNmse) << check.name;
}

class SparPipelineTest : public EngineTest {
 protected:
  // Runs encode + render of one golden case; `render` chooses the cameras.
  void runCase(const std::string& name, bool assumeStatic, bool pathCameras = false) {
    GoldenCase g(name);
    PackedModel model = PackedModel::open(tinyModelPath());
    SparPipeline pipe(eng(), model, {.profile = true, .keepIntermediates = true});
    const SparConfig& c = pipe.config();
    SparRequest req;
    req.images = prepareFrames(g, c.imageHeight, c.imageWidth);
    req.plan.views = int64_t(g.files().size());
    req.plan.inputs = g.inputs();
    req.plan.targets = g.targets();
    req.assumeStatic = assumeStatic;
    // The prepared images are bit-exact with the reference's (x / 255 rounded to float).
    const std::vector<double> images = g.doubles("images");
    ASSERT_EQ(images.size(), req.images.size());
    size_t differ = 0;
    for (size_t i = 0; i < images.size(); ++i) differ += req.images[i] != float(images[i]);
    EXPECT_EQ(differ, 0u);

    pipe.encode(req);
    for (const StageCheck& s : kEncodeChecks) expectStage(eng(), pipe, g, s);
    if (pathCameras) {
      RenderCameras cams;
      const std::vector<float> c2w = g.floats("render_c2w"), k = g.floats("render_fxfycxcy");
      for (size_t j = 0; j < k.size() / 4; ++j) {
        std::array<float, 16> m;
        std::array<float, 4> kk;
        std::copy_n(c2w.begin() + j * 16, 16, m.begin());
        std::copy_n(k.begin() + j * 4, 4, kk.begin());
        cams.c2w.push_back(m);
        cams.fxfycxcy.push_back(kk);
      }
      pipe.render(cams);
    } else {
      pipe.renderTargets();
    }
    for (const StageCheck& s : kRenderChecks) expectStage(eng(), pipe, g, s);
    // Every stage that ran reported a time; none that did not.
    for (const StageTime& t : pipe.stageTimes()) {
      EXPECT_GE(t.gpuMs, 0.0) << t.name;
      if (assumeStatic) {
        EXPECT_TRUE(t.name != "dino_v3" && t.name != "cv_drp") << t.name;
      }
    }
  }
};

TEST_F(SparPipelineTest, AssumeStaticInterleavedMatchesReference) { runCase("static", true); }

}  // namespace
}  // namespace spar::test
