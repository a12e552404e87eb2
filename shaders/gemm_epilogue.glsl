// The GEMM kernels' epilogue (gemm.comp, gemm_tiled.comp, gemm_lanes.comp, gemm_coopmat.comp):
// the bias binding and what happens to a finished sum before it is stored (STORE_OUT, with
// ACCUMULATE added to what y holds). Included after the kernel's ACT and HAS_BIAS constants.
// Host side: engine/ops/linear.cpp.
//
// SCALED (a layer scale: DINOv3's ls1 / ls2 gammas): the bias binding holds one RGBA texel a
// column, (bias, scale, 0, 0), and the result is scale * act(sum + bias). With ACCUMULATE a
// layer-scaled residual branch, x += gamma * fc(h), is one dispatch instead of three (the GEMM,
// a multiply, an add), with the same operations in the same order.
layout(constant_id = 16) const bool SCALED = false;
TEXEL_INPUT(2, BIAS, SCALED ? 4 : 1)  // bound to w (never read) when HAS_BIAS is false

float gemm_epilogue(float v, int biasTexel) {
  if (SCALED) {
    const vec4 biasScale = fetch_BIAS(biasTexel);
    return activate(v + biasScale.x, ACT) * biasScale.y;
  }
  if (HAS_BIAS) v += fetch_BIAS(biasTexel).x;
  return activate(v, ACT);
}
