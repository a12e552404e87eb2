// Hiera's window layout and q pooling (model/sam2_windows.h); the kernel is
// model/shaders/sam2_windows.comp (variants sam2_window_partition, _merge, sam2_max_pool2x2).
#include "model/sam2_windows.h"
#include "model/model_shaders.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct WindowsPush {
  uint32_t total, h, w, c, win, nwx;
};

void dispatch(Recorder& rec, const char* variant, const std::string& op, const Tensor& in, const Tensor& out,
              const WindowsPush& push) {
  Engine& engine = rec.engine();
  if (ops::overlaps(out, in)) throw Error(op + ": output overlaps the input");
  if (uint64_t(in.numel()) > 0x7fffffffull || uint64_t(out.numel()) > 0x7fffffffull)
    throw Error(op + ": too many values for 32-bit indexing");
  if (uint64_t(in.bytes()) > engine.device().bindingRangeLimit() ||
      uint64_t(out.bytes()) > engine.device().bindingRangeLimit())
    throw Error(op + ": a tensor exceeds one storage binding");
  if (out.numel() == 0) return;
  registerModelShaders();  // model/shaders/sam2_windows.comp
  const Kernel& kernel = engine.kernel(
      {variant, {Bind::Read, Bind::Write}, sizeof(WindowsPush), {ops::elementLocalX(engine.caps()), 1, 1}});
  const ops::Grid grid =
      ops::linearGrid(engine.caps(), ops::ceilDiv(uint64_t(out.numel()), uint64_t(ops::elementLocalX(engine.caps()))), op);
  rec.dispatch(kernel, {Arg::in(in), Arg::out(out)}, push, grid.x, grid.y, 1, op);
}

void requireMap(const Tensor& t, const std::string& op, const char* what) {
  if (!t.defined()) throw Error(op + ": missing " + what);
  ops::requireF32(t, op, what);
  if (t.rank() != 3) throw Error(op + ": " + what + " must be [H, W, C], got " + t.describe());
}

// windows as [nW, w * w, C] or [nW, w, w, C]
void requireWindows(const Tensor& t, int64_t nW, int64_t window, int64_t C, const std::string& op) {
  if (!t.defined()) throw Error(op + ": missing windows");
  ops::requireF32(t, op, "windows");
  const bool flat = t.rank() == 3 && t.dim(0) == nW && t.dim(1) == window * window && t.dim(2) == C;
  const bool square = t.rank() == 4 && t.dim(0) == nW && t.dim(1) == window && t.dim(2) == window && t.dim(3) == C;
  if (!flat && !square)
    throw Error(op + ": windows must be [" + std::to_string(nW) + ", " + std::to_string(window * window) + ", " +
                std::to_string(C) + "], got " + t.describe());
}

}  // namespace

void sam2ChannelsLast(Recorder& rec, const Tensor& x, const Tensor& y) {
  const std::string op = "sam2ChannelsLast";
  if (!x.defined() || !y.defined()) throw Error(op + ": missing tensor");
  ops::requireF32(x, op, "x");
  ops::requireF32(y, op, "y");
  if (x.rank() != 4 || x.dim(0) != 1) throw Error(op + ": x must be [1, C, H, W], got " + x.describe());
  const int64_t C = x.dim(1), H = x.dim(2), W = x.dim(3);
  if (y.rank() != 2 || y.dim(0) != H * W || y.dim(1) != C)
    throw Error(op + ": y must be [" + std::to_string(H * W) + ", " + std::to_string(C) + "], got " + y.describe());
  dispatch(rec, "sam2_channels_last", op, x, y, {uint32_t(y.numel()), uint32_t(H), uint32_t(W), uint32_t(C), 0, 0});
}

void sam2AddNearestUp2x(Recorder& rec, const Tensor& lateral, const Tensor& coarse, const Tensor& y) {
  const std::string op = "sam2AddNearestUp2x";
  requireMap(lateral, op, "lateral");
  requireMap(coarse, op, "coarse");
  requireMap(y, op, "y");
  const int64_t H = lateral.dim(0), W = lateral.dim(1), C = lateral.dim(2);
  if (H % 2 || W % 2 || coarse.dim(0) != H / 2 || coarse.dim(1) != W / 2 || coarse.dim(2) != C || y.shape() != lateral.shape())
    throw Error(op + ": lateral " + lateral.describe() + ", coarse " + coarse.describe() + " and y " + y.describe() +
                " do not fit (coarse must be half the lateral's even size)");
  Engine& engine = rec.engine();
  if (ops::overlaps(y, coarse)) throw Error(op + ": y overlaps coarse");
  if (uint64_t(y.numel()) > 0x7fffffffull) throw Error(op + ": too many values for 32-bit indexing");
  if (uint64_t(y.bytes()) > engine.device().bindingRangeLimit()) throw Error(op + ": y exceeds one storage binding");
  if (y.numel() == 0) return;
  registerModelShaders();  // model/shaders/sam2_windows.comp
  const Kernel& kernel = engine.kernel({"sam2_add_nearest_up2x", {Bind::Read, Bind::Write, Bind::Read},
                                        sizeof(WindowsPush), {ops::elementLocalX(engine.caps()), 1, 1}});
  const WindowsPush push{uint32_t(y.numel()), uint32_t(H), uint32_t(W), uint32_t(C), 0, 0};
  const ops::Grid grid =
      ops::linearGrid(engine.caps(), ops::ceilDiv(uint64_t(y.numel()), uint64_t(ops::elementLocalX(engine.caps()))), op);
  rec.dispatch(kernel, {Arg::in(lateral), Arg::out(y), Arg::in(coarse)}, push, grid.x, grid.y, 1, op);
}

int64_t sam2WindowsAlong(int64_t extent, int64_t window) { return (extent + window - 1) / window; }

// partition (map -> windows) and merge (windows -> map) check and dispatch alike
static void windowLayout(Recorder& rec, bool partition, const Tensor& map, int64_t window, const Tensor& windows) {
  const std::string op = partition ? "sam2WindowPartition" : "sam2WindowMerge";
  requireMap(map, op, "x");
  if (window <= 0) throw Error(op + ": window must be positive");
  const int64_t H = map.dim(0), W = map.dim(1), C = map.dim(2);
  const int64_t nWx = sam2WindowsAlong(W, window), nW = sam2WindowsAlong(H, window) * nWx;
  requireWindows(windows, nW, window, C, op);
  const Tensor& out = partition ? windows : map;
  dispatch(rec, partition ? "sam2_window_partition" : "sam2_window_merge", op, partition ? map : windows, out,
           {uint32_t(out.numel()), uint32_t(H), uint32_t(W), uint32_t(C), uint32_t(window), uint32_t(nWx)});
}

void sam2WindowPartition(Recorder& rec, const Tensor& x, int64_t window, const Tensor& windows) {
  windowLayout(rec, true, x, window, windows);
}

void sam2WindowMerge(Recorder& rec, const Tensor& windows, int64_t window, const Tensor& x) {
  windowLayout(rec, false, x, window, windows);
}

void sam2MaxPool2x2(Recorder& rec, const Tensor& x, const Tensor& y) {
  const std::string op = "sam2MaxPool2x2";
  if (!x.defined() || !y.defined()) throw Error(op + ": missing tensor");
  ops::requireF32(x, op, "x");
  ops::requireF32(y, op, "y");
  if (x.rank() != 4) throw Error(op + ": x must be [B, H, W, C], got " + x.describe());
  const int64_t B = x.dim(0), H = x.dim(1), W = x.dim(2), C = x.dim(3);
  if (y.rank() != 4 || y.dim(0) != B || y.dim(1) != H / 2 || y.dim(2) != W / 2 || y.dim(3) != C)
    throw Error(op + ": y must be [" + std::to_string(B) + ", " + std::to_string(H / 2) + ", " + std::to_string(W / 2) +
                ", " + std::to_string(C) + "], got " + y.describe());
  dispatch(rec, "sam2_max_pool2x2", op, x, y, {uint32_t(y.numel()), uint32_t(H), uint32_t(W), uint32_t(C), 0, 0});
}

}  // namespace spar
