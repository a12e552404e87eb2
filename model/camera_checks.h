// What a render camera must be before the engine renders it (include/spar/request.h's
// RenderCameras; spar render --cameras): finite; a rotation (the upper 3x3 of c2w) orthonormal
// with determinant +1 within kRotationTolerance (max |R^T R - I| entry, |det - 1|); a position
// within kMaxTranslation of the canonical camera (SPAR's scenes are normalized to a few units:
// a thousand times that is a unit or a typing mistake, and overflows the ray maps at 1e38); the
// bottom row 0 0 0 1; normalized intrinsics fx/W, fy/H in (0, kMaxFocal], cx/W, cy/H within
// +-kMaxCentre.
#pragma once
#include <array>
#include <string>

namespace spar {

constexpr double kRotationTolerance = 1e-3;
constexpr double kMaxTranslation = 1e3;
constexpr double kMaxFocal = 1e3;
constexpr double kMaxCentre = 1e2;

// "" for a camera the engine renders, else what is wrong with it (one line, no prefix).
std::string renderCameraProblem(const std::array<float, 16>& c2w, const std::array<float, 4>& fxfycxcy);

}  // namespace spar
