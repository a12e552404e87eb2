// One argument for /bin/sh, single-quoted: the programs that run a Python helper through
// std::system (spar-modes' PyTorch reference, spar-bench's CPU peer) pass paths that may hold
// spaces or quotes.
#pragma once
#include <string>

namespace spar {

inline std::string shellQuote(const std::string& s) {
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

}  // namespace spar
