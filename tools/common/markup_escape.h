// Text for HTML and XML (element text and quoted attribute values): &, <, > and " escaped.
// The result page (index_page.cpp) and the self-test's JUnit report (selftest_junit.cpp).
#pragma once
#include <string>

namespace spar::cli {

inline std::string escapeMarkup(const std::string& s) {
  std::string out;
  out.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

}  // namespace spar::cli
