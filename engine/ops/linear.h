// Linear layer y = act(x W^T + b) on shaders/gemm.comp.
#pragma once
#include "engine/ops/activation.h"
#include "engine/recorder.h"
#include "spar/engine_options.h"

namespace spar {

// Register-block and workgroup shape of the GEMM kernel for a device.
struct GemmTiles {
  int rowsPerInvocation, colsPerInvocation, localX, localY;
  int kUnroll;  // k texels per loop iteration
  // The workgroup is one subgroup of localX lanes sharing its colsPerInvocation columns
  // (gemm.comp's SHARED_COLUMNS; localY is 1).
  bool sharedColumns = false;
};
// llvmpipe with subgroup shuffles and full subgroups: 4 rows a lane, the subgroup's lanes sharing
// 32 columns (16 where N is smaller), measured on three llvmpipe generations. Other CPU devices:
// register blocks measured per driver generation (engine/ops/cpu_tiles.h) and by the work of the
// product (multiply-adds M * N * K: a bigger block only where the run time it saves outweighs
// its compile time); GPUs: small blocks, many invocations. tuning.gemmTiles
// (SPAR_GEMM_TILES="RM,RN,LX,LY,KU") forces register blocks of those tiles (for tuning with spar-bench).
GemmTiles chooseGemmTiles(const DeviceCaps& caps, const KernelTuning& tuning, double multiplyAdds, int64_t N);

// x: [rows..., K] with w: [N, K], or x: [B, M, K] with w: [B, N, K] (batched);
// bias: [N] or undefined; y: [rows..., N] (f32 or f16). x, w, bias may be f32 or f16.
// Tensors above the device's binding limits are processed in row chunks. With accumulate the
// result is added to what y holds, y = y + act(x W^T + b): a residual add fused into the GEMM's
// epilogue (every GEMM kernel's ACCUMULATE), one dispatch instead of two. A bias made by
// layerScaleEpilogue() scales each column too: y (+)= gamma * act(x W^T + b).
void linear(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
            Activation act = Activation::None, bool accumulate = false);

// The bias of a layer-scaled linear (shaders/gemm_epilogue.glsl, SCALED): f32 [N, 4] texels
// (bias[n] or 0, gamma[n], 0, 0). bias: [N] or undefined, gamma: [N], f32 or f16. Made once,
// with a host round trip: call it while loading weights, not while recording a request.
Tensor layerScaleEpilogue(Engine& engine, const Tensor& bias, const Tensor& gamma);

// The convolutions' im2col products (engine/ops/conv2d.cpp, conv_transpose2d.cpp) on the lanes
// GEMM (shaders/gemm_lanes.comp; only where KernelPlan::gemmLanesSplitK): y[m * ldy + n] =
// act(sum_k a[m][k] * b[n][k] + bias[m]) for fp32 a: [M, K], b: [N, K], bias: [M] or undefined;
// y: the elements from the first row's start to the last written (a block of columns of a wider
// matrix). scatterK = k > 0 (transposed convolutions, kernel = stride = k): row m = (co, a, e)
// and column n = (i, j) of an input plane scatterW wide go to y[co * ldy + (i k + a) * scatterW k
// + j k + e], bias [M / k^2]. Every binding must fit the device.
void gemmLanesRowBias(Recorder& rec, const Tensor& a, const Tensor& b, const Tensor& bias, const Tensor& y, int64_t ldy,
                      Activation act, int scatterK = 0, int64_t scatterW = 0);

}  // namespace spar
