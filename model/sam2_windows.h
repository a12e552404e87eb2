// Hiera's window layout, q pooling and the FPN's top-down step on the engine (kernel: model/shaders/sam2_windows.comp;
// reference: reference/spar_reference/sam2.py window_partition, window_unpartition,
// max_pool_2x2; official hieradet). Channel-last tokens, f32:
//
//   sam2WindowPartition  x [H, W, C] -> windows [nW, w * w, C] (or [nW, w, w, C]), nW =
//                        ceil(H / w) * ceil(W / w) row-major; the padding (bottom, right) zeros
//   sam2WindowMerge      windows [nW, w * w, C] -> x [H, W, C], the windows of a grid padded to
//                        ceil(H / w) * w by ceil(W / w) * w, cropped to H x W
//   sam2MaxPool2x2       x [B, H, W, C] -> y [B, H / 2, W / 2, C] (floor, as MaxPool2d(2, 2))
//   sam2AddNearestUp2x   y [H, W, C] = lateral + coarse [H / 2, W / 2, C] upsampled x2 by
//                        nearest neighbour (the FPN neck's top-down step; H, W even)
//   sam2ChannelsLast     x [1, C, H, W] -> y [H * W, C] (NCHW maps to channel-last tokens)
//
// Recorded into the caller's Recorder; nothing runs on the CPU.
#pragma once
#include "engine/engine.h"
#include "engine/recorder.h"

namespace spar {

// Windows of side `window` along each axis of an H x W map: ceil(extent / window).
int64_t sam2WindowsAlong(int64_t extent, int64_t window);

void sam2WindowPartition(Recorder& rec, const Tensor& x, int64_t window, const Tensor& windows);
void sam2WindowMerge(Recorder& rec, const Tensor& windows, int64_t window, const Tensor& x);
void sam2MaxPool2x2(Recorder& rec, const Tensor& x, const Tensor& y);
void sam2ChannelsLast(Recorder& rec, const Tensor& x, const Tensor& y);
void sam2AddNearestUp2x(Recorder& rec, const Tensor& lateral, const Tensor& coarse, const Tensor& y);

}  // namespace spar
