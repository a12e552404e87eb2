// SPAR's sin-cos position codes (utils/pe_utils.py; reference reference/spar_reference/spar.py
// sincos_1d / sincos_2d), as host tables.
//
// They depend only on sizes (grid, view count, width), like weights, so they are computed once per
// size in double on the host and uploaded: the GPU's built-in sin/cos carry loose precision
// guarantees on many devices (Vulkan allows 2^-11 absolute error), while a double table rounded
// once to float is as exact as float allows, on every device.
#pragma once
#include <cstdint>
#include <vector>

namespace spar {

// [positions.size(), dim]: concat(sin(p f_k), cos(p f_k)), f_k = 10000^(-k / (dim/2)), k < dim/2.
std::vector<double> sincos1d(int64_t dim, const std::vector<double>& positions);
// [gh * gw, dim]: token k gets concat(1D code (dim/2) of k / gh, 1D code (dim/2) of k % gh)
// (the official meshgrid order; (row, column) for square grids).
std::vector<double> sincos2d(int64_t dim, int64_t gh, int64_t gw);

// The codes the model feeds its embedders, as floats:
// image tokens [views, gh*gw, D]: concat(2D code (D/2) of the patch, 1D code (D/2) of the view index)
std::vector<float> imageTokenCode(int64_t d, int64_t gh, int64_t gw, int64_t views);
// camera tokens [views, D]: 1D code (D) of the view index
std::vector<float> cameraTokenCode(int64_t d, int64_t views);
// the gating code [gh*gw, D]: 2D code (D) of the patch
std::vector<float> gatingCode(int64_t d, int64_t gh, int64_t gw);

}  // namespace spar
