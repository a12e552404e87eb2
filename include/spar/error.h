// The one exception type of SPAR: every problem (bad input, a file that cannot be read, a
// device failure) is a spar::Error whose what() is a single readable line, naming the file,
// option or stage concerned.
#pragma once
#include <stdexcept>
#include <string>

#include "spar/export.h"

namespace spar {

struct SPAR_API Error : std::runtime_error {
  using std::runtime_error::runtime_error;
};

}  // namespace spar
