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
};
// CPU devices (llvmpipe): register blocks measured per driver generation (engine/ops/
// cpu_tiles.h) and by the work of the product (multiply-adds M * N * K: a bigger block only
// where the run time it saves outweighs its compile time); GPUs: small blocks, many invocations.
// tuning.gemmTiles (SPAR_GEMM_TILES="RM,RN,LX,LY,KU") overrides (for tuning with spar-bench).
GemmTiles chooseGemmTiles(const DeviceCaps& caps, const KernelTuning& tuning, double multiplyAdds);

// x: [rows..., K] with w: [N, K], or x: [B, M, K] with w: [B, N, K] (batched);
// bias: [N] or undefined; y: [rows..., N] (f32 or f16). x, w, bias may be f32 or f16.
// Tensors above the device's binding limits are processed in row chunks.
void linear(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
            Activation act = Activation::None);

}  // namespace spar
