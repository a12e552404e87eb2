// EngineOptions (include/spar/engine_options.h): the environment is one way to fill it, every
// malformed value is a one-line error naming its variable, and set fields win.
#include <gtest/gtest.h>

#include <cstdlib>
#include <string>

#include "spar/engine_options.h"
#include "spar/error.h"

namespace spar::test {
namespace {

// Sets the variables for one test and clears them after, whatever happens.
class Environment : public ::testing::Test {
 protected:
  void set(const char* name, const char* value) {
    setenv(name, value, 1);
    names_.push_back(name);
  }
  void TearDown() override {
    for (const char* n : names_) unsetenv(n);
  }
  std::vector<const char*> names_;
};

std::string errorOf(const EngineOptions& base = {}) {
  try {
    EngineOptions::fromEnvironment(base);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

TEST_F(Environment, EmptyEnvironmentChangesNothing) {
  for (const char* n : {"SPAR_DEVICE", "SPAR_VALIDATION", "SPAR_LOG_PIPELINES", "SPAR_PROFILE", "SPAR_GEMM_TILES",
                        "SPAR_ATTENTION_TILES", "SPAR_CONV_TILES", "SPAR_CONVT_TILES", "SPAR_LINE_GROUP",
                        "SPAR_ROW_PADDING", "SPAR_GEMM_ROW_GROUPS"})
    unsetenv(n);
  const EngineOptions o = EngineOptions::fromEnvironment();
  EXPECT_TRUE(o.device.empty());
  EXPECT_FALSE(o.validation || o.logPipelines || o.profileDispatches);
  EXPECT_FALSE(o.tuning.gemmTiles || o.tuning.attentionTiles || o.tuning.convTiles || o.tuning.convTransposeTiles ||
               o.tuning.lineGroup || o.tuning.padAliasedRows || o.tuning.gemmRowGroups);
}

TEST_F(Environment, EveryKnobIsRead) {
  set("SPAR_DEVICE", "llvmpipe");
  set("SPAR_VALIDATION", "1");
  set("SPAR_LOG_PIPELINES", "1");
  set("SPAR_PROFILE", "1");
  set("SPAR_GEMM_TILES", "4,16,8,8,2");
  set("SPAR_ATTENTION_TILES", "8,8,8");
  set("SPAR_CONV_TILES", "8,1,8,8,1");
  set("SPAR_CONVT_TILES", "4,1,4,8,1");
  set("SPAR_LINE_GROUP", "1,16,4");
  set("SPAR_ROW_PADDING", "0");
  set("SPAR_GEMM_ROW_GROUPS", "3");
  const EngineOptions o = EngineOptions::fromEnvironment();
  EXPECT_EQ(o.device, "llvmpipe");
  EXPECT_TRUE(o.validation && o.logPipelines && o.profileDispatches);
  EXPECT_EQ(*o.tuning.gemmTiles, (std::array<int, 5>{4, 16, 8, 8, 2}));
  EXPECT_EQ(*o.tuning.attentionTiles, (std::array<int, 3>{8, 8, 8}));
  EXPECT_EQ(*o.tuning.convTiles, (std::array<int, 5>{8, 1, 8, 8, 1}));
  EXPECT_EQ(*o.tuning.convTransposeTiles, (std::array<int, 5>{4, 1, 4, 8, 1}));
  EXPECT_EQ(*o.tuning.lineGroup, (std::array<int, 3>{1, 16, 4}));
  EXPECT_EQ(o.tuning.padAliasedRows, std::optional<bool>(false));
  EXPECT_EQ(o.tuning.gemmRowGroups, std::optional<int>(3));
}

TEST_F(Environment, FieldsSetByTheProgramWin) {
  set("SPAR_DEVICE", "llvmpipe");
  set("SPAR_GEMM_TILES", "4,16,8,8,2");
  EngineOptions base;
  base.device = "1";
  base.tuning.gemmTiles = std::array<int, 5>{2, 8, 8, 8, 1};
  const EngineOptions o = EngineOptions::fromEnvironment(base);
  EXPECT_EQ(o.device, "1");
  EXPECT_EQ(*o.tuning.gemmTiles, (std::array<int, 5>{2, 8, 8, 8, 1}));
}

TEST_F(Environment, MalformedValuesNameTheirVariable) {
  const std::pair<const char*, const char*> bad[] = {
      {"SPAR_GEMM_TILES", "4,16,8"},       {"SPAR_GEMM_TILES", "4,16,8,8,2,1"}, {"SPAR_GEMM_TILES", "4,x,8,8,2"},
      {"SPAR_GEMM_TILES", "0,16,8,8,2"},   {"SPAR_ATTENTION_TILES", "8,6,8"},   {"SPAR_CONV_TILES", "8,1,8,-8,1"},
      {"SPAR_CONVT_TILES", "4 1 4 8 1"},   {"SPAR_LINE_GROUP", "2,16,4"},       {"SPAR_LINE_GROUP", "1,12,4"},
      {"SPAR_GEMM_ROW_GROUPS", "-1"},      {"SPAR_GEMM_ROW_GROUPS", "4097"},    {"SPAR_GEMM_ROW_GROUPS", "8x"},
  };
  for (const auto& [name, value] : bad) {
    set(name, value);
    const std::string e = errorOf();
    EXPECT_NE(e.find(name), std::string::npos) << name << "=" << value << ": " << e;
    EXPECT_EQ(e.find('\n'), std::string::npos) << e;
    unsetenv(name);
  }
}

TEST(KernelTuning, ProgramValuesAreValidatedToo) {
  KernelTuning t;
  t.attentionTiles = std::array<int, 3>{4, 10, 8};
  EXPECT_THROW(t.validate(), Error);
  t.attentionTiles = std::array<int, 3>{4, 8, 8};
  EXPECT_NO_THROW(t.validate());
}

}  // namespace
}  // namespace spar::test
