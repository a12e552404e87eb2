// 2-D convolution (PyTorch nn.Conv2d) on shaders/conv2d.comp.
#pragma once
#include <cstdint>

#include "engine/ops/activation.h"
#include "engine/recorder.h"
#include "spar/engine_options.h"

namespace spar {

// Register block and workgroup shape of the conv2d kernel: each invocation computes
// channels x rows x cols outputs; a workgroup is localX x localY invocations.
struct ConvTiles {
  int channels, rows, cols, localX, localY;
};
// For a kh x kw kernel with cout output channels: CPU devices (llvmpipe) get big register
// blocks (fewer channels for big kernels, to bound compile time; rows instead of channels
// when cout is small), GPUs small ones. tuning.convTiles (SPAR_CONV_TILES="RC,RY,RX,LX,LY") overrides (for
// tuning). localY == 1 selects the flat walk over output blocks (shaders/conv2d.comp, FLAT).
ConvTiles chooseConvTiles(const DeviceCaps& caps, const KernelTuning& tuning, int64_t kh, int64_t kw,
                          int64_t cout = INT64_MAX);

struct Conv2dParams {
  int stride = 1;   // the same along y and x
  int padY = 0, padX = 0;  // zero padding on each side
  Activation act = Activation::None;
  // A quantized w (Q8 / Q4) is the matrix [Cout, Cin*kh*kw]: its kernel size goes here
  // (0: from w's shape; given with an f32 w, it must be w's).
  int kernelH = 0, kernelW = 0;
};

// x: [N, Cin, H, W], w: [Cout, Cin, kh, kw] (PyTorch layout), bias: [Cout] or undefined,
// y: [N, Cout, Ho, Wo] with Ho = (H + 2 padY - kh) / stride + 1 (likewise Wo). All f32, except
// that w may be a block-quantized kernel (engine/tensor.h DType::Q8 / Q4): the matrix
// [Cout, Cin*kh*kw] with params.kernelH / kernelW, dequantized as the kernel reads it (by
// conv2d.comp's register blocks, or by the GPU family's implicit GEMM, KernelPlan::quantizedConv).
// y = act(conv(x, w) + bias). Kernels up to 32x32; beyond about 7x7 the register-blocked
// kernel gets slow (a 14x14 stride-14 patch embedding runs at ~1.5 GFLOPS on llvmpipe):
// express patch embeddings as patchify + linear instead.
void conv2d(Recorder& rec, const Tensor& x, const Tensor& w, const Tensor& bias, const Tensor& y,
            const Conv2dParams& params = {});

// Output size along one axis, PyTorch's formula; throws if the kernel does not fit.
int64_t conv2dOutputSize(int64_t in, int64_t kernel, int stride, int pad);

}  // namespace spar
