// Stiff and extreme cases at the model level (engineering.md, issue "SPAR on the engine"), each
// the whole pipeline against the float64 reference on the tiny model (goldens and model variants
// from tests/python/make_spar_goldens.py). Thresholds are the plain cases' (pipeline_check.cpp)
// unless a case says otherwise; every stage must also be free of NaN and Inf.
#include <algorithm>

#include "pipeline_check.h"
#include "test_support.h"

namespace spar::test {
namespace {

class SparStiffTest : public EngineTest {};

// All five frames the same image: CV-DRP sees identical pairs, the pose encoder identical views.
TEST_F(SparStiffTest, AllViewsIdentical) { runGoldenCase(eng(), "identical_views", {}); }

// Frame 2 (an input and the canonical view) all black: 2*img-1 = -1 everywhere, DINOv3's
// normalization of a constant image.
TEST_F(SparStiffTest, OneViewAllBlack) { runGoldenCase(eng(), "black_view", {}); }

// CV-DRP head bias +40: P(dynamic) = 1 at every pixel, so every input token is replaced by
// mask_token + code (gating with s = 0 everywhere).
TEST_F(SparStiffTest, EverythingDynamic) {
  runGoldenCase(eng(), "all_dynamic", {.model = goldenPath("all_dynamic.spar")});
}

// CV-DRP head bias -40: P(dynamic) ~ 4e-18, every token kept (s = 1 up to 4e-18).
TEST_F(SparStiffTest, EverythingStatic) {
  runGoldenCase(eng(), "all_static", {.model = goldenPath("all_static.spar")});
}

// canonical_k_head predicting focal 1001.25 (a very narrow field of view: rays nearly parallel)
// and 0.001 (extremely wide: ray directions nearly in the image plane).
TEST_F(SparStiffTest, ExtremeFocalLarge) {
  runGoldenCase(eng(), "focal_large", {.model = goldenPath("focal_large.spar")});
}
TEST_F(SparStiffTest, ExtremeFocalSmall) {
  runGoldenCase(eng(), "focal_small", {.model = goldenPath("focal_small.spar")});
}

}  // namespace
}  // namespace spar::test
