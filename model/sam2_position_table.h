// SAM2.1's Hiera position table on the engine (kernel: model/shaders/sam2_position_table.comp;
// reference: reference/spar_reference/sam2.py position_embedding; official
// hieradet.Hiera._get_pos_embed).
//
//   background [1, C, Hb, Wb] f32  sam2.image_encoder.trunk.pos_embed (7x7, or 14x14 for b+)
//   window     [1, C, w, w]   f32  sam2.image_encoder.trunk.pos_embed_window
//   table      [side * side, C] f32: the background resized bicubically to side x side
//              (PyTorch's align_corners=False, A = -0.75) plus the window table tiled,
//              token-major as Hiera's tokens are laid out. side must be a multiple of w.
//
// Input-independent: a SAM2 stage computes it once per model load, not per view.
#pragma once
#include "engine/engine.h"
#include "engine/recorder.h"

namespace spar {

void sam2PositionTable(Recorder& rec, const Tensor& background, const Tensor& window, const Tensor& table);

}  // namespace spar
