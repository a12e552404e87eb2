// The two kinds of failure of the `spar` command, told apart by their exit codes: a command
// line that cannot mean anything (exit 2), and everything else found wrong on the way (files,
// device, model: exit 1). Both print as one line "spar: error: <message>".
#pragma once
#include "spar/error.h"

namespace spar::cli {

struct UsageError : Error {
  using Error::Error;
};

constexpr int kExitOk = 0, kExitRuntime = 1, kExitUsage = 2;

}  // namespace spar::cli
