// The self-tests of every device side by side (selftest_table.h).
#include "tools/common/selftest_table.h"

#include <algorithm>
#include <cstdio>
#include <string>

namespace spar::cli {
namespace {

constexpr int kCell = 18;

// A check's cell: "pass 12.3 ms", "FAIL 12.3 ms", "FAIL (error)"; "-" where the device has no
// such check (a profile without 16-bit storage has no fp16-weight check).
std::string cell(const SelftestReport& r, const std::string& name) {
  for (const auto* list : {&r.opChecks, &r.modelChecks})
    for (const SelftestCheck& c : *list) {
      if (c.name != name) continue;
      if (!c.error.empty()) return "FAIL (error)";
      char b[48];
      std::snprintf(b, sizeof b, "%s %.1f ms", c.passed() ? "pass" : "FAIL", c.ms);
      return b;
    }
  return r.error.empty() ? "-" : "not run";
}

void row(const std::string& label, const std::vector<std::string>& cells, int labelWidth) {
  std::printf("%-*s", labelWidth, label.c_str());
  for (const std::string& c : cells) std::printf("  %-*s", kCell, c.c_str());
  std::printf("\n");
}

}  // namespace

void printDeviceTable(const std::vector<SelftestReport>& reports) {
  std::printf("spar selftest --all-devices: %zu device%s\n", reports.size(), reports.size() == 1 ? "" : "s");
  std::vector<std::string> names, heads;
  for (size_t i = 0; i < reports.size(); ++i) {
    const SelftestReport& r = reports[i];
    heads.push_back("[" + std::to_string(i + 1) + "]");
    std::printf("  [%zu] %s%s%s\n", i + 1, r.device.c_str(), r.profile.empty() ? "" : ", profile ",
                r.profile.c_str());
    if (!r.error.empty()) std::printf("      could not be used: %s\n", r.error.c_str());
    for (const auto* list : {&r.opChecks, &r.modelChecks})
      for (const SelftestCheck& c : *list)
        if (std::find(names.begin(), names.end(), c.name) == names.end()) names.push_back(c.name);
  }
  int width = 24;
  for (const std::string& n : names) width = std::max(width, static_cast<int>(n.size()));
  row("check", heads, width);
  for (const std::string& n : names) {
    std::vector<std::string> cells;
    for (const SelftestReport& r : reports) cells.push_back(cell(r, n));
    row(n, cells, width);
  }
  std::vector<std::string> messages, verdicts;
  for (const SelftestReport& r : reports) {
    messages.push_back(!r.error.empty() ? "-" : r.validation ? std::to_string(r.validationMessages) : "layer absent");
    verdicts.push_back((r.ok() ? "PASS " : "FAIL ") + std::to_string(r.passed()) + "/" + std::to_string(r.total()));
  }
  row("validation messages", messages, width);
  row("verdict", verdicts, width);
}

}  // namespace spar::cli
