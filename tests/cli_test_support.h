// Shared by the tests that run the built `spar` program: its path SPAR_CLI, which
// samples/CMakeLists.txt defines for the test targets it lists (spar_wire_render_test), and the
// helpers they use to run it (runValidated, probeVideo: tests/test_support.h).
#pragma once
#ifndef SPAR_CLI
#error "SPAR_CLI (path of the built spar binary) is defined by samples/CMakeLists.txt"
#endif

#include "tests/test_support.h"
