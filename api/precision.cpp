// spar/precision.h: the names of the weight precisions.
#include "spar/precision.h"

#include "spar/error.h"

namespace spar {

std::vector<std::string> precisionNames() { return {"fp32", "fp16", "q8", "q4"}; }

std::string precisionName(Precision precision) {
  return precisionNames().at(static_cast<size_t>(precision));
}

Precision parsePrecision(const std::string& name) {
  const std::vector<std::string> names = precisionNames();
  for (size_t i = 0; i < names.size(); ++i)
    if (names[i] == name) return static_cast<Precision>(i);
  throw Error("--precision must be fp32, fp16, q8 or q4, not '" + name + "'");
}

}  // namespace spar
