// spar/request.h: the checks of a view plan.
#include <set>
#include <string>

#include "spar/error.h"
#include "spar/request.h"

namespace spar {

void ViewPlan::validate() const {
  if (views < 1) throw Error("no views given");
  if (inputs.empty()) throw Error("at least one input view is needed");
  std::set<int64_t> seen;
  for (const auto* list : {&inputs, &targets})
    for (size_t i = 0; i < list->size(); ++i) {
      const int64_t v = (*list)[i];
      if (v < 0 || v >= views)
        throw Error("view position " + std::to_string(v) + " is outside the sequence of " + std::to_string(views) +
                    " frames");
      if (i > 0 && v <= (*list)[i - 1]) throw Error("view positions must be increasing");
      if (!seen.insert(v).second) throw Error("view " + std::to_string(v) + " is both an input and a target");
    }
}

}  // namespace spar
