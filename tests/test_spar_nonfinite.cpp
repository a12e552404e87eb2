// Non-finite values never leave the engine silently (through the built `spar` on the tiny
// photometric fixture model, F32): a NaN or infinite weight is refused when it is read, naming
// the tensor; a finite but huge weight (3e38) that overflows is a one-line error naming the
// first stage with non-finite values; render cameras that are not finite, not a rotation or
// absurdly far are refused before any work. Every case: exit 1, one line, no output directory.
#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "tests/golden_support.h"
#include "tests/cli_test_support.h"
#include "tests/test_support.h"

namespace spar::test {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

const fs::path& scratch() { return scratchDir("spar_nonfinite"); }

// A copy of the fixture's tiny.spar with `count` values of `tensor` from element 0 set to `value`.
fs::path damagedModel(const std::string& name, const std::string& tensor, float value, int count = 1) {
  const fs::path src = goldenPath("tiny.spar"), dst = scratch() / (name + ".spar");
  std::ifstream in(src, std::ios::binary);
  std::vector<char> bytes{std::istreambuf_iterator<char>(in), {}};
  uint64_t headerLen = 0;
  std::memcpy(&headerLen, bytes.data(), 8);
  const json header = json::parse(std::string(bytes.data() + 8, headerLen));
  const uint64_t begin = 8 + headerLen + header.at(tensor).at("data_offsets")[0].get<uint64_t>();
  EXPECT_EQ(header.at(tensor).at("dtype"), "F32");
  for (int i = 0; i < count; ++i) std::memcpy(bytes.data() + begin + 4 * i, &value, 4);
  std::ofstream(dst, std::ios::binary).write(bytes.data(), std::streamsize(bytes.size()));
  return dst;
}

CommandResult render(const fs::path& model, const fs::path& out, const std::vector<std::string>& extra = {}) {
  fs::remove_all(out);
  std::vector<std::string> argv = {SPAR_CLI, "render", "--model", model.string(), "--frames"};
  for (int i = 0; i < 5; ++i) argv.push_back(goldenPath("frame_" + std::to_string(i) + ".png"));
  for (const char* a : {"--inputs", "0,2,4"}) argv.push_back(a);
  argv.insert(argv.end(), extra.begin(), extra.end());
  argv.push_back("--out");
  argv.push_back(out.string());
  return runValidated(argv, scratch());
}

void expectRefused(const CommandResult& r, const fs::path& out, const std::string& expected) {
  EXPECT_EQ(r.code, 1) << r.err;
  // Progress lines ("spar: ...") and exactly one error line, the last.
  size_t errors = 0, begin = 0;
  std::string last;
  while (begin < r.err.size()) {
    const size_t end = r.err.find('\n', begin);
    last = r.err.substr(begin, end - begin);
    EXPECT_EQ(last.rfind("spar: ", 0), 0u) << "a line not from spar: " << last;
    errors += last.rfind("spar: error: ", 0) == 0;
    begin = end == std::string::npos ? r.err.size() : end + 1;
  }
  EXPECT_EQ(errors, 1u) << r.err;
  EXPECT_EQ(last.rfind("spar: error: ", 0), 0u) << r.err;
  EXPECT_NE(r.err.find(expected), std::string::npos) << "expected '" << expected << "' in: " << r.err;
  EXPECT_FALSE(fs::exists(out)) << out;
  for (const auto& e : fs::directory_iterator(out.parent_path()))
    EXPECT_EQ(e.path().filename().string().find(out.filename().string() + ".tmp"), std::string::npos) << e.path();
}

TEST(spar_nonfinite, NanWeightIsRefusedNamingTheTensor) {
  const std::string tensor = "cv_drp.estimator.dpt_decoder.up_blocks.1.3.weight";
  const fs::path out = scratch() / "nan_out";
  expectRefused(render(damagedModel("nan", tensor, std::numeric_limits<float>::quiet_NaN()), out), out,
                "tensor '" + tensor + "' element 0 is NaN");
  expectRefused(render(damagedModel("inf", "image_tokenizer.1.weight", -std::numeric_limits<float>::infinity()), out),
                out, "tensor 'image_tokenizer.1.weight' element 0 is infinite");
}

TEST(spar_nonfinite, OverflowNamesTheFirstStage) {
  // One patch's worth of the first token's weights at 3e38: finite in the file, infinite in
  // the first stage's sums.
  const fs::path out = scratch() / "huge_out";
  expectRefused(render(damagedModel("huge", "image_tokenizer.1.weight", 3e38f, 768), out), out,
                "encoding the views: stage image_tokens produced");
}

TEST(spar_nonfinite, UntouchedModelStillRenders) {
  // The checks themselves: the same command on the model as made renders (a check that
  // always fired would pass the tests above).
  const fs::path out = scratch() / "ok_out";
  const CommandResult r = render(damagedModel("same", "image_tokenizer.1.weight", 0.0f, 0), out);
  EXPECT_EQ(r.code, 0) << r.err;
  EXPECT_TRUE(fs::exists(out / "view_00.png"));
}

TEST(spar_nonfinite, BadRenderCamerasAreRefusedBeforeWork) {
  const auto transforms = [&](const std::string& name, const json& matrix) {
    const fs::path p = scratch() / (name + ".json");
    json doc = {{"fl_x", 100}, {"fl_y", 100}, {"w", 128}, {"h", 128}, {"frames", {{{"transform_matrix", matrix}}}}};
    std::ofstream(p) << doc.dump();
    return p;
  };
  const json far = {{1, 0, 0, 1e38}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
  const json zero = {{0, 0, 0, 0}, {0, 0, 0, 0}, {0, 0, 0, 0}, {0, 0, 0, 1}};
  const json skew = {{1, 0.2, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
  const json mirror = {{-1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
  const json fine = {{1, 0, 0, 0.1}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}};
  const fs::path out = scratch() / "cam_out";
  const fs::path model = goldenPath("tiny.spar");
  expectRefused(render(model, out, {"--cameras", transforms("far", far).string()}), out, "camera 0: position 1e+38");
  expectRefused(render(model, out, {"--cameras", transforms("zero", zero).string()}), out, "not orthonormal");
  expectRefused(render(model, out, {"--cameras", transforms("skew", skew).string()}), out, "not orthonormal");
  expectRefused(render(model, out, {"--cameras", transforms("mirror", mirror).string()}), out, "det -1");
  const CommandResult ok = render(model, out, {"--cameras", transforms("fine", fine).string()});
  EXPECT_EQ(ok.code, 0) << ok.err;
}

}  // namespace
}  // namespace spar::test
