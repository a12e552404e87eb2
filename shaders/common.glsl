// Shared by every kernel: output element type, activation functions.
// Conventions: constant_id 0-2 are the workgroup size; shapes come as push constants.
#extension GL_EXT_control_flow_attributes : enable
// Texel buffers as textureBuffer read with texelFetch, no sampler: a samplerBuffer compiles to a
// sampled image of Dim Buffer, which SPIR-V 1.6 (Vulkan 1.3 and later drivers) no longer allows
// and the validation layer reports on such devices.
#extension GL_EXT_samplerless_texture_functions : require

#ifndef OUT_F16
#define OUT_F16 0
#endif
#if OUT_F16
#extension GL_EXT_shader_16bit_storage : require
#extension GL_EXT_shader_explicit_arithmetic_types_float16 : require
#define OUT_T float16_t
// Saturate instead of overflowing to inf: a value beyond fp16's range keeps its sign
// and the largest finite magnitude, so one hot activation cannot poison what follows.
#define TO_OUT(v) float16_t(clamp((v), -65504.0, 65504.0))
#else
#define OUT_T float
#define TO_OUT(v) (v)
#endif
// A GEMM's output element: written, or with ACCUMULATE (a residual add fused into the GEMM,
// y = y + act(x W^T + b)) added to what y holds. Each element has one writer, so reading it back
// is race-free.
#define STORE_OUT(i, v) y[i] = TO_OUT(ACCUMULATE ? float(y[i]) + (v) : (v))

// Inputs read as texels: fetch_NAME(i) is the vec4 texelFetch gives of texel i, COMPONENTS
// (1 or 4) floats of an R or RGBA texel (fp32 or fp16: the texel format converts). The *_sx
// twin of every variant of a shader that declares its inputs so (STORAGE_INPUTS=1, made by
// cmake/EmbedShaders.cmake) reads the same values from a storage buffer of 32-bit words
// instead, for devices whose texel buffers are too short (65536 texels is all Vulkan
// guarantees; engine/kernel_plan.h, storageInputs). Bit BINDING of STORAGE_INPUT_F16 (set per
// pipeline from the tensors bound: engine/pipeline.cpp) says the binding holds fp16: its words
// are pairs of halves, unpacked with unpackHalf2x16, so reading fp16 needs no 16-bit storage.
#if defined(STORAGE_INPUTS) && STORAGE_INPUTS
layout(constant_id = 63) const int STORAGE_INPUT_F16 = 0;  // kStorageInputF16ConstantId
#define TEXEL_INPUT(BINDING, NAME, COMPONENTS)                                                  \
  layout(binding = BINDING) readonly buffer NAME##_words { uint NAME##_w[]; };                  \
  vec4 fetch_##NAME(int i) {                                                                    \
    if ((STORAGE_INPUT_F16 & (1 << (BINDING))) != 0) {                                          \
      if ((COMPONENTS) == 4) return vec4(unpackHalf2x16(NAME##_w[2 * i]), unpackHalf2x16(NAME##_w[2 * i + 1])); \
      const vec2 pair = unpackHalf2x16(NAME##_w[i >> 1]);                                        \
      return vec4((i & 1) != 0 ? pair.y : pair.x, 0.0, 0.0, 1.0);                                \
    }                                                                                           \
    if ((COMPONENTS) == 4)                                                                      \
      return uintBitsToFloat(uvec4(NAME##_w[4 * i], NAME##_w[4 * i + 1], NAME##_w[4 * i + 2], NAME##_w[4 * i + 3])); \
    return vec4(uintBitsToFloat(NAME##_w[i]), 0.0, 0.0, 1.0);                                   \
  }
#else
#define TEXEL_INPUT(BINDING, NAME, COMPONENTS)    \
  layout(binding = BINDING) uniform textureBuffer NAME; \
  vec4 fetch_##NAME(int i) { return texelFetch(NAME, i); }
#endif

#define ACT_NONE 0
#define ACT_GELU 1        // exact erf GELU (PyTorch nn.GELU())
#define ACT_QUICK_GELU 2  // x * sigmoid(1.702 x) (CLIP)
#define ACT_SILU 3
#define ACT_SIGMOID 4
#define ACT_RELU 5

// Sigmoid without overflow: exp of a negative argument only.
float sigmoid_stable(float x) {
  float e = exp(-abs(x));
  return x >= 0.0 ? 1.0 / (1.0 + e) : e / (1.0 + e);
}

// Complementary error function with fractional error < 1.2e-7 everywhere (Chebyshev
// fit, Numerical Recipes 6.2), so GELU keeps full relative accuracy in its negative tail.
float erfc_accurate(float x) {
  float z = abs(x);
  float t = 1.0 / (1.0 + 0.5 * z);
  float poly = -1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418 + t * (-0.18628806 +
               t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277))))))));
  float r = t * exp(-z * z + poly);
  return x >= 0.0 ? r : 2.0 - r;
}

float gelu_erf(float x) { return 0.5 * x * erfc_accurate(-x * 0.70710678118654752); }

float activate(float x, int act) {
  if (act == ACT_GELU) return gelu_erf(x);
  if (act == ACT_QUICK_GELU) return x * sigmoid_stable(1.702 * x);
  if (act == ACT_SILU) return x * sigmoid_stable(x);
  if (act == ACT_SIGMOID) return sigmoid_stable(x);
  if (act == ACT_RELU) return max(x, 0.0);
  return x;
}
