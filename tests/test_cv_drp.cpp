// model/cv_drp (CV-DRP) against the PyTorch reference in float64: the model-level goldens of
// tests/python/make_spar_goldens.py (fixture spar_goldens: tiny perturbed model, cases
// interleaved / odd_targets, and the models whose head bias is +40 / -40), plus goldens made
// by tests/python/make_cv_drp_golden.py within that fixture (the official pairs, all views identical).
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>

#include "model/cv_drp.h"
#include "model/packed_model.h"
#include "tests/golden_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;
using Pairs = std::vector<std::pair<int64_t, int64_t>>;

// Measured on lavapipe (fp32 engine vs float64 reference), worst over all cases below:
// pair_fused 6.7e-15, pair_tokens 2.4e-14, pair and view logits 7.6e-16, prob 3.1e-15, except
// prob of the all_static model, 2.1e-12: there prob = sigmoid(~-40) ~ e^logit, whose relative
// error is the logit's absolute error (~1e-6 at |logit| 40, fp32's resolution). Thresholds:
// 1e-12 for tokens and logits (40x margin), 1e-10 for prob (50x). Dropping one decoder bias
// (up_blocks.1.3) gives logits NMSE 1e-6, six orders above.
constexpr double kMaxNmse = 1e-12;
constexpr double kMaxProbNmse = 1e-10;

// make_cv_drp_golden.py's view pairs and all-identical case (fixture spar_goldens: cv_drp/).
std::string cvDrpGolden(const std::string& what) { return goldenPath("cv_drp/" + what); }

// The model, its weights and the stage, built once per test.
struct Stage {
  explicit Stage(Engine& engine, const std::string& modelFile = "tiny.spar")
      : model(PackedModel::open(goldenPath(modelFile))),
        config(SparConfig::fromJson(model.config(), model.path())),
        weights(engine, model),
        cvDrp(engine, weights, config) {}
  PackedModel model;
  SparConfig config;
  WeightSet weights;
  CvDrp cvDrp;
};

// [1, V, n, D] float64 tokens -> f32 [V, n, D] on the device.
Tensor uploadTokens(Engine& engine, const NpyArray& a) {
  const Shape s(a.shape.begin() + (a.shape.size() == 4 ? 1 : 0), a.shape.end());
  return engine.fromFloats(s, a.toFloats());
}

struct Outputs {
  Tensor logits, prob;
  CvDrpTrace trace;
};

Outputs makeOutputs(Engine& engine, const SparConfig& c, size_t views) {
  const Shape s{int64_t(views), 1, c.patchSize * c.patchesH(), c.patchSize * c.patchesW()};
  return {engine.tensor(s), engine.tensor(s), {}};
}

void expectMatches(Engine& engine, const Tensor& got, const std::vector<double>& want, const std::string& what,
                   double maxNmse = kMaxNmse) {
  const std::vector<float> g = engine.download(got);
  ASSERT_EQ(g.size(), want.size()) << what;
  const ErrorStats e = compare(g, want);
  std::printf("  %-28s NMSE %.3e  max abs %.3e\n", what.c_str(), e.nmse, e.maxAbs);
  EXPECT_EQ(e.nonFinite, 0u) << what;
  EXPECT_LE(e.nmse, maxNmse) << what;
}

// Binary masks prob > threshold identical, except where the reference is within 1e-4 of it.
void expectSameMask(Engine& engine, const Tensor& prob, const std::vector<double>& want, float threshold,
                    const std::string& what) {
  const std::vector<float> got = engine.download(prob);
  ASSERT_EQ(got.size(), want.size());
  size_t differ = 0, dynamic = 0;
  for (size_t i = 0; i < got.size(); ++i) {
    dynamic += want[i] > threshold;
    if ((got[i] > threshold) != (want[i] > threshold) && std::abs(want[i] - threshold) >= 1e-4) ++differ;
  }
  std::printf("  %-28s %zu of %zu pixels dynamic, %zu differ\n", what.c_str(), dynamic, got.size(), differ);
  EXPECT_EQ(differ, 0u) << what;
}

// ---------------------------------------------------------------------------------------------

TEST(CvDrpPairs, MatchReferenceFunction) {
  const std::string path = cvDrpGolden("pairs.json");
  const nlohmann::json table = nlohmann::json::parse(std::ifstream(path));
  for (const auto& [name, mode] : {std::pair{"input", CvDrpMode::Input}, std::pair{"target", CvDrpMode::Target}})
    for (int64_t v = 1; v <= 6; ++v) {
      Pairs want;
      for (const auto& p : table.at(name).at(size_t(v - 1))) want.emplace_back(p.at(0).get<int64_t>(), p.at(1).get<int64_t>());
      EXPECT_EQ(cvDrpPairs(v, mode), want) << name << " " << v << " views";
    }
  EXPECT_THROW(cvDrpPairs(0, CvDrpMode::Input), Error);
}

struct GoldenCaseSpec {
  std::string dir, model;
};
void PrintTo(const GoldenCaseSpec& c, std::ostream* os) { *os << c.dir; }

class CvDrpGoldenTest : public EngineTest, public ::testing::WithParamInterface<GoldenCaseSpec> {};

// Inputs and targets recorded into one recorder, as the pipeline does (the second call reuses
// and regrows the first one's scratch buffers), each against the reference's goldens.
TEST_P(CvDrpGoldenTest, InputsAndTargetsMatchReference) {
  const GoldenCaseSpec spec = GetParam();
  // Every case (all_dynamic / all_static included) is made by make_spar_goldens.py: a missing
  // one is a broken fixture, not something to skip.
  ASSERT_TRUE(fs::exists(goldenPath(spec.dir)) && fs::exists(goldenPath(spec.model)))
      << "fixture spar_goldens has no case " << spec.dir << " / model " << spec.model;
  const GoldenCase g(spec.dir);
  Stage st(eng(), spec.model);
  const SparConfig& c = st.config;
  const Tensor dino = uploadTokens(eng(), g.array("dino"));
  const Tensor img = uploadTokens(eng(), g.array("img_tokens"));
  const Tensor ray = uploadTokens(eng(), g.array("ray_tokens"));

  const std::vector<std::pair<std::string, CvDrpMode>> subsets = {{"cv_drp_input", CvDrpMode::Input},
                                                                  {"cv_drp_target", CvDrpMode::Target}};
  const std::vector<std::vector<int64_t>> views = {g.inputs(), g.targets()};
  std::vector<Outputs> out;
  TransformerWorkspace ws;
  Recorder rec(eng());
  for (size_t s = 0; s < subsets.size(); ++s) {
    out.push_back(makeOutputs(eng(), c, views[s].size()));
    st.cvDrp.forward(rec, dino, img, ray, views[s], subsets[s].second, c.patchesH(), c.patchesW(), out[s].logits,
                     out[s].prob, ws, &out[s].trace);
  }
  rec.run();

  for (size_t s = 0; s < subsets.size(); ++s) {
    const std::string& name = subsets[s].first;
    SCOPED_TRACE(spec.dir + " " + name);
    // the pairs the reference used
    const std::vector<double> refPairs = g.doubles(name + ".pairs");
    Pairs want;
    for (size_t i = 0; i + 1 < refPairs.size(); i += 2) want.emplace_back(int64_t(refPairs[i]), int64_t(refPairs[i + 1]));
    EXPECT_EQ(out[s].trace.pairs, want);
    expectMatches(eng(), out[s].trace.pairFused, g.doubles(name + ".pair_fused"), name + ".pair_fused");
    expectMatches(eng(), out[s].trace.pairTokens, g.doubles(name + ".pair_tokens"), name + ".pair_tokens");
    expectMatches(eng(), out[s].trace.pairLogits, g.doubles(name + ".pair_logits"), name + ".pair_logits");
    expectMatches(eng(), out[s].logits, g.doubles(name + ".logits"), name + ".logits");
    expectMatches(eng(), out[s].prob, g.doubles(name + ".prob"), name + ".prob", kMaxProbNmse);
    expectSameMask(eng(), out[s].prob, g.doubles(name + ".prob"), c.maskThreshold, name + ".binary");
    // and the reference's own mask agrees with its probabilities
    const std::vector<double> prob = g.doubles(name + ".prob"), binary = g.doubles(name + ".binary");
    for (size_t i = 0; i < prob.size(); ++i) ASSERT_EQ(binary[i] != 0.0, prob[i] > c.maskThreshold) << i;
  }
}

INSTANTIATE_TEST_SUITE_P(Goldens, CvDrpGoldenTest,
                         ::testing::Values(GoldenCaseSpec{"interleaved", "tiny.spar"},
                                           GoldenCaseSpec{"odd_targets", "tiny.spar"},
                                           // head bias +40 / -40: P(dynamic) 1 / ~4e-18 everywhere
                                           GoldenCaseSpec{"all_dynamic", "all_dynamic.spar"},
                                           GoldenCaseSpec{"all_static", "all_static.spar"}),
                         [](const auto& info) { return info.param.dir; });

class CvDrpTest : public EngineTest {};

// Stiff case: every view has the same tokens (view 0 of the interleaved case), 5 views as inputs
// and as targets (odd: the middle pairing), and one view alone (paired with itself). Every pair
// then sees two copies of one view, so every view's logits equal the single view's; against the
// float64 reference as well.
TEST_F(CvDrpTest, IdenticalViewsMatchReference) {
  const std::string dir = cvDrpGolden("identical");
  const auto npy = [&](const std::string& name) { return readNpy(dir + "/" + name + ".npy"); };
  const auto ref = [&](const std::string& name) { return npy(name).toDoubles(); };
  Stage st(eng());
  const SparConfig& c = st.config;
  const Tensor dino = uploadTokens(eng(), npy("tokens.dino"));
  const Tensor img = uploadTokens(eng(), npy("tokens.img"));
  const Tensor ray = uploadTokens(eng(), npy("tokens.ray"));
  const std::vector<int64_t> all = {0, 1, 2, 3, 4};
  struct Run {
    std::string name;
    CvDrpMode mode;
    std::vector<int64_t> views;
  };
  const std::vector<Run> runs = {{"input", CvDrpMode::Input, all}, {"target", CvDrpMode::Target, all},
                                 {"single", CvDrpMode::Input, {0}}};
  TransformerWorkspace ws;
  std::vector<float> single;
  for (const Run& r : runs) {
    SCOPED_TRACE(r.name);
    Outputs o = makeOutputs(eng(), c, r.views.size());
    Recorder rec(eng());
    st.cvDrp.forward(rec, dino, img, ray, r.views, r.mode, c.patchesH(), c.patchesW(), o.logits, o.prob, ws, &o.trace);
    rec.run();
    expectMatches(eng(), o.trace.pairLogits, ref(r.name + ".pair_logits"), r.name + ".pair_logits");
    expectMatches(eng(), o.logits, ref(r.name + ".logits"), r.name + ".logits");
    expectMatches(eng(), o.prob, ref(r.name + ".prob"), r.name + ".prob", kMaxProbNmse);
    expectSameMask(eng(), o.prob, ref(r.name + ".prob"), c.maskThreshold, r.name + ".binary");
    const std::vector<float> logits = eng().download(o.logits);
    if (r.name == "single") single = logits;
    else {
      // every view like view 0 (the engine's batch positions compute alike)
      const size_t hw = logits.size() / r.views.size();
      const std::vector<double> first(logits.begin(), logits.begin() + long(hw));
      for (size_t v = 1; v < r.views.size(); ++v) {
        const std::vector<float> view(logits.begin() + long(v * hw), logits.begin() + long((v + 1) * hw));
        EXPECT_LE(compare(view, first).nmse, 1e-13) << "view " << v;
      }
    }
  }
}

// The stage refuses what it cannot compute, with a one-line error.
TEST_F(CvDrpTest, RejectsBadShapesAndPlans) {
  Stage st(eng());
  const SparConfig& c = st.config;
  const int64_t n = c.tokensPerView(), d = c.d;
  const Tensor tok = eng().tensor({3, n, d}), narrow = eng().tensor({3, n, d / 2});
  TransformerWorkspace ws;
  Recorder rec(eng());
  Outputs o = makeOutputs(eng(), c, 2);
  const auto run = [&](const Tensor& dino, const std::vector<int64_t>& views, const Tensor& logits) {
    st.cvDrp.forward(rec, dino, tok, tok, views, CvDrpMode::Input, c.patchesH(), c.patchesW(), logits, o.prob, ws);
  };
  EXPECT_THROW(run(narrow, {0, 1}, o.logits), Error);             // DINO width != D
  EXPECT_THROW(run(tok, {1, 0}, o.logits), Error);                // not increasing
  EXPECT_THROW(run(tok, {0, 3}, o.logits), Error);                // outside the sequence
  EXPECT_THROW(run(tok, {0, 1, 2}, o.logits), Error);             // 3 views, outputs for 2
  EXPECT_THROW(run(tok, {0, 1}, eng().tensor({2, 1, 8, 8})), Error);  // wrong output size
  EXPECT_EQ(rec.pending(), 0u);
}

// Wall time of one tiny forward (3 inputs: 2 pairs) after a warm-up call; printed, not asserted.
// Calls after the first allocate nothing.
// CVDRP_PROFILE=1 also prints every dispatch's GPU time.
TEST_F(CvDrpTest, TinyForwardTimeAndBufferReuse) {
  const GoldenCase g("interleaved");
  Stage st(eng());
  const SparConfig& c = st.config;
  const Tensor dino = uploadTokens(eng(), g.array("dino"));
  const Tensor img = uploadTokens(eng(), g.array("img_tokens"));
  const Tensor ray = uploadTokens(eng(), g.array("ray_tokens"));
  Outputs o = makeOutputs(eng(), c, g.inputs().size());
  TransformerWorkspace ws;
  double ms = 0;
  int allocations = 0;
  for (int i = 0; i < 3; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    Recorder rec(eng(), std::getenv("CVDRP_PROFILE") != nullptr);
    st.cvDrp.forward(rec, dino, img, ray, g.inputs(), CvDrpMode::Input, c.patchesH(), c.patchesW(), o.logits, o.prob,
                     ws);
    rec.run();
    for (const auto& t : rec.timings()) std::printf("    %-20s %.3f ms\n", t.label.c_str(), t.ms);
    // buffers planned by the first call, reused by the next ones
    if (i == 0) allocations = st.cvDrp.allocations();
    EXPECT_EQ(st.cvDrp.allocations(), allocations) << "call " << i;
    ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    std::printf("  forward %d: %.1f ms (%d inputs, %lldx%lld tokens)\n", i, ms, int(g.inputs().size()),
                (long long)c.patchesH(), (long long)c.patchesW());
  }
  expectMatches(eng(), o.logits, g.doubles("cv_drp_input.logits"), "logits after repeated calls");
}

}  // namespace
}  // namespace spar::test
