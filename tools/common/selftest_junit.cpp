// spar selftest --junit (selftest_junit.h).
#include "tools/common/selftest_junit.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "spar/error.h"
#include "tools/common/markup_escape.h"

namespace spar::cli {
namespace {

std::string xml(const std::string& s) { return escapeMarkup(s); }

std::string number(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.3e", v);
  return b;
}

// What was measured against what was allowed, in words (the failure's message, and the
// passing check's output).
std::string measured(const SelftestCheck& c) {
  if (!c.error.empty()) return "error: " + c.error;
  std::string s = "family " + c.family + "; ";
  if (!c.detail.empty()) s += c.detail;
  else
    s += "nmse " + number(c.nmse) + " (limit " + number(c.maxNmse) + "), max abs " + number(c.maxAbs) + " (limit " +
         (std::isinf(c.maxAbsLimit) ? std::string("none") : number(c.maxAbsLimit)) + ")";
  if (!c.finite) s += "; non-finite values";
  return s;
}

void testcase(std::ostringstream& o, const std::string& suite, const SelftestCheck& c) {
  char time[32];
  std::snprintf(time, sizeof time, "%.4f", c.ms / 1000.0);
  o << "    <testcase classname=\"" << suite << "\" name=\"" << xml(c.name) << "\" time=\"" << time << "\">\n";
  if (!c.passed()) o << "      <failure message=\"" << xml(measured(c)) << "\"/>\n";
  o << "      <system-out>" << xml(measured(c)) << "</system-out>\n    </testcase>\n";
}

// One device's <testsuite>; adds its tests, failures and seconds to the totals.
void testsuite(std::ostringstream& o, const SelftestReport& r, size_t& allTests, size_t& allFailures,
               double& allSeconds) {
  char time[32];
  if (!r.error.empty()) {
    o << "  <testsuite name=\"spar selftest on " << xml(r.device) << "\" tests=\"1\" failures=\"1\" errors=\"0\" "
      << "time=\"0\">\n    <testcase classname=\"selftest.device\" name=\"device\" time=\"0\">\n"
      << "      <failure message=\"" << xml("could not be used: " + r.error) << "\"/>\n    </testcase>\n"
      << "  </testsuite>\n";
    allTests += 1, allFailures += 1;
    return;
  }
  size_t tests = r.total() + 1, failures = (r.total() - r.passed()) + (r.validationMessages > 0);
  // The suite's time: a model stage with several outputs gives each of its checks the stage's
  // time (the same value, one after another), counted once here.
  double seconds = 0, previous = -1;
  for (const auto* list : {&r.opChecks, &r.modelChecks})
    for (const SelftestCheck& c : *list) {
      if (c.ms != previous) seconds += c.ms / 1000.0;
      previous = c.ms;
    }
  std::snprintf(time, sizeof time, "%.4f", seconds);
  o << "  <testsuite name=\"spar selftest on " << xml(r.device) << "\" tests=\"" << tests << "\" failures=\""
    << failures << "\" errors=\"0\" time=\"" << time << "\">\n";
  for (const SelftestCheck& c : r.opChecks) testcase(o, "selftest.ops", c);
  for (const SelftestCheck& c : r.modelChecks) testcase(o, "selftest.model", c);
  o << "    <testcase classname=\"selftest.validation\" name=\"validation layer messages\" time=\"0\">\n";
  const std::string said = r.validation ? std::to_string(r.validationMessages) + " messages" : "the layer is not installed";
  if (r.validationMessages) o << "      <failure message=\"" << xml(said) << "\"/>\n";
  o << "      <system-out>" << xml(said) << "</system-out>\n    </testcase>\n  </testsuite>\n";
  allTests += tests, allFailures += failures, allSeconds += seconds;
}

}  // namespace

void checkJunitWritable(const std::string& path) {
  namespace fs = std::filesystem;
  fs::path dir = fs::path(path).parent_path();
  if (dir.empty()) dir = ".";
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) throw Error("cannot write the JUnit report " + path + ": no directory " + dir.string());
  if (::access(dir.c_str(), W_OK) != 0) throw Error("cannot write the JUnit report " + path + ": " + dir.string() + " is not writable");
  if (fs::is_directory(path, ec)) throw Error("cannot write the JUnit report " + path + ": it is a directory");
}

void writeSelftestJunit(const std::string& path, const std::vector<SelftestReport>& reports) {
  std::ostringstream suites;
  size_t tests = 0, failures = 0;
  double seconds = 0;
  for (const SelftestReport& r : reports) testsuite(suites, r, tests, failures, seconds);
  std::ostringstream o;
  char time[32];
  std::snprintf(time, sizeof time, "%.4f", seconds);
  o << "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<testsuites name=\"spar selftest\" tests=\"" << tests
    << "\" failures=\"" << failures << "\" errors=\"0\" time=\"" << time << "\">\n"
    << suites.str() << "</testsuites>\n";

  const std::string tmp = path + ".tmp-" + std::to_string(::getpid());
  {
    std::ofstream f(tmp, std::ios::binary);
    f << o.str();
    f.close();
    if (!f) {
      std::error_code ec;
      std::filesystem::remove(tmp, ec);
      throw Error("cannot write the JUnit report " + path);
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) {
    std::filesystem::remove(tmp, ec);
    throw Error("cannot write the JUnit report " + path);
  }
}

}  // namespace spar::cli
