// INTERNAL, not part of the public API (include/spar/): the engine and its general ops, for the
// op-level benchmark (tools/spar_bench/bench_cases.*), the one program that records single ops
// on its own. Everything else a program does goes through include/spar/. These interfaces change
// with the engine; nothing installed depends on them.
#pragma once
#include "engine/engine.h"
#include "engine/kernel_plan.h"
#include "engine/ops/attention.h"
#include "engine/ops/conv2d.h"
#include "engine/ops/conv_transpose2d.h"
#include "engine/ops/linear.h"
#include "engine/ops/norm.h"
#include "engine/ops/reduce_channels.h"
#include "engine/pipeline.h"
#include "engine/recorder.h"
#include "engine/uniform_floats.h"
