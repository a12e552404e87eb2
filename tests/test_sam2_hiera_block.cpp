// model/sam2_hiera_block (one Hiera block of SAM2.1, with model/sam2_windows' layout kernels)
// against the PyTorch reference's hiera_block in float64 (tests/python/make_sam2_block_golden.py,
// fixture op_goldens): windows padded at the bottom and right, an odd window, a q-pooling
// transition inside padded windows (grid cropped after pooling), a global block and a global
// q-pooling one, the official windows of 14 on 64x64 and 7 on 32x32 (padded to 70 and 35), and
// the stiff cases: attention logits near 1e3, input rows of mean 1e4. The reference itself matches a per-window, per-head float64 sum of the
// official formulas (reference/tests/test_reference_sam2.py).
#include <filesystem>
#include <fstream>
#include <map>

#include <nlohmann/json.hpp>

#include "formats/npy.h"
#include "model/sam2_hiera_block.h"
#include "model/sam2_windows.h"
#include "tests/golden_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;

class Sam2HieraBlockTest : public EngineTest {
 protected:
  // Bounds: the transformer block's (tests/test_transformer_block.cpp) unless a case says why not.
  void check(const std::string& name, double maxNmse = 5e-13, double maxAbs = 1e-5) {
    const std::string dir = opGoldenPath("sam2_block/" + name);
    std::ifstream in(dir + "/spec.json");
    const nlohmann::json spec = nlohmann::json::parse(in);
    Sam2BlockSpec s;
    s.dim = spec["dim"], s.dimOut = spec["dim_out"], s.heads = spec["heads"], s.window = spec["window"];
    s.qPool = spec["q_pool"].get<int>() != 0;
    const int64_t H = spec["height"], W = spec["width"];
    std::map<std::string, Tensor> weights;
    for (const auto& e : fs::directory_iterator(dir)) {
      const std::string file = e.path().filename().string();
      if (file == "x.npy" || file == "y.npy" || e.path().extension() != ".npy") continue;
      const NpyArray a = readNpy(e.path().string());
      weights["b." + file.substr(0, file.size() - 4)] = eng().fromFloats(a.shape, a.toFloats());
    }
    const NpyArray x = readNpy(dir + "/x.npy", {H, W, s.dim});
    const int64_t Ho = s.qPool ? H / 2 : H, Wo = s.qPool ? W / 2 : W;
    const NpyArray y = readNpy(dir + "/y.npy", {Ho, Wo, s.dimOut});
    const Tensor tx = eng().fromFloats({H, W, s.dim}, x.toFloats());
    GuardedOutput out(eng(), {Ho, Wo, s.dimOut});
    Recorder rec(eng());
    sam2HieraBlock(rec, s, [&](const std::string& k) { return weights.count(k) ? weights.at(k) : Tensor(); }, "b.", tx,
                   out.tensor());
    rec.run();
    out.expectAllWritten();
    // fp32 against float64 through two LayerNorms, attention and two GEMM pairs
    expectClose(out.read(), y.toDoubles(), maxNmse, maxAbs, name);
  }
};

TEST_F(Sam2HieraBlockTest, PaddedWindowsKeepBiasOnlyKeys) { check("padded_windows"); }
TEST_F(Sam2HieraBlockTest, OddWindow) { check("odd_window"); }
TEST_F(Sam2HieraBlockTest, QPoolingInsidePaddedWindows) { check("q_pool_padded"); }
TEST_F(Sam2HieraBlockTest, GlobalAttention) { check("global"); }
TEST_F(Sam2HieraBlockTest, GlobalQPooling) { check("global_q_pool"); }
// 196- and 49-token windows over 4096 and 1024 outputs: sums 10x longer than the small cases'
// and 8x more outputs to take the maximum of (measured 1.45e-5 on values up to 6.7, NMSE
// 2.6e-13): the attention op's max-abs bound (tests/test_attention.cpp, spar selftest).
TEST_F(Sam2HieraBlockTest, Window14PaddedOn64x64) { check("window_14_on_64", 5e-13, 1e-4); }
TEST_F(Sam2HieraBlockTest, Window7PaddedOn32x32) { check("window_7_on_32", 5e-13, 1e-4); }
// Logits up to 2.3e3: the attention op's bounds for logits near 1e3 (measured NMSE 2.4e-12).
TEST_F(Sam2HieraBlockTest, GlobalAttentionLogitsNear1e3) { check("global_logits_1e3", 1e-9, 1e-4); }
// Outputs near 1e4 (the residual carries the input), whose fp32 spacing is 9.8e-4: two of
// those (measured 1.03e-3, NMSE 1.4e-15).
TEST_F(Sam2HieraBlockTest, RowsOfMean1e4) { check("rows_of_mean_1e4", 5e-13, 2e-3); }

TEST_F(Sam2HieraBlockTest, WindowLayoutRoundTrips) {
  // partition then merge is the identity on the map; the padding is zeros
  const int64_t H = 7, W = 5, C = 3, w = 4;
  std::vector<float> v(size_t(H * W * C));
  for (size_t i = 0; i < v.size(); ++i) v[i] = float(i) + 1.0f;
  const Tensor x = eng().fromFloats({H, W, C}, v);
  const Tensor windows = eng().tensor({4, w * w, C});
  GuardedOutput back(eng(), {H, W, C});
  Recorder rec(eng());
  sam2WindowPartition(rec, x, w, windows);
  sam2WindowMerge(rec, windows, w, back.tensor());
  rec.run();
  EXPECT_EQ(back.read(), v);
  const std::vector<float> win = eng().download(windows);
  // window 1 (top right) holds columns 4..7 of rows 0..3: only column 4 is inside the map
  for (int64_t r = 0; r < w; ++r)
    for (int64_t c = 0; c < w; ++c)
      for (int64_t ch = 0; ch < C; ++ch) {
        const float got = win[size_t(((1 * w * w) + r * w + c) * C + ch)];
        EXPECT_EQ(got, c == 0 ? v[size_t((r * W + 4) * C + ch)] : 0.0f) << r << "," << c;
      }
  EXPECT_THROW(sam2WindowPartition(rec, x, w, eng().tensor({3, w * w, C})), Error);
}

}  // namespace
}  // namespace spar::test
