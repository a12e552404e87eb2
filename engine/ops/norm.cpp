// LayerNorm and RMSNorm dispatch; the kernel is shaders/norm.comp.
#include "engine/ops/norm.h"

#include "engine/ops/dispatch_helpers.h"

namespace spar {
namespace {

struct NormPush {
  uint32_t rows, heads, dh;
  uint32_t xStride, xCol0, yStride, yCol0;
  float eps;
  uint32_t weightHeads;  // heads that share a row of the weight (0: all of them)
};

enum class Norm { Layer, Rms };

// Normalizes `heads` lines of dh values starting at column xCol0 of every row of x2 [rows, Cx]
// into y2 [rows, Cy] at yCol0. weight and bias are [dh] or undefined; with weightHeads > 0 the
// weight is [heads / weightHeads, dh], a row for each weightHeads consecutive heads.
void normLines(Recorder& rec, Norm norm, const Tensor& x2, int64_t xCol0, const Tensor& y2, int64_t yCol0,
               int64_t heads, int64_t dh, const Tensor& weight, const Tensor& bias, float eps, const std::string& op,
               int64_t weightHeads = 0) {
  Engine& engine = rec.engine();
  const int64_t rows = x2.dim(0), cx = x2.dim(1), cy = y2.dim(1);
  if (!(eps >= 0.0f)) throw Error(op + ": eps must be >= 0");
  const bool inPlace = ops::sameMemory(x2, y2);
  if (inPlace && xCol0 != yCol0) throw Error(op + ": in place needs the same column in x and y");
  if (!inPlace && ops::overlaps(x2, y2)) throw Error(op + ": y overlaps x without being x");
  if (rows == 0 || heads == 0) return;
  if (uint64_t(rows) * uint64_t(heads) > 0xffffffffull || cx > 0x7fffffff || cy > 0x7fffffff)
    throw Error(op + ": too many lines for 32-bit indexing");

  const bool vec4 = dh % 4 == 0 && cx % 4 == 0 && cy % 4 == 0 && xCol0 % 4 == 0 && yCol0 % 4 == 0;
  const ops::LineGroup g = ops::lineGroupFor(engine, vec4 ? dh / 4 : dh, true, rows * heads);
  const bool rms = norm == Norm::Rms;
  std::vector<Bind> bindings =
      inPlace ? std::vector<Bind>{Bind::ReadWrite} : std::vector<Bind>{Bind::Read, Bind::Write};
  bindings.push_back(Bind::Read);            // weight
  if (!rms) bindings.push_back(Bind::Read);  // bias
  const std::string shader = std::string(rms ? (inPlace ? "rmsnorm_inplace" : "rmsnorm") : (inPlace ? "layernorm_inplace" : "layernorm")) +
                             (g.subgroup ? "_sg" : "");
  const Kernel& kernel = engine.kernel(
      {shader, bindings, sizeof(NormPush), {g.localX, g.localY, 1, g.split, vec4, weight.defined(), bias.defined()}});

  for (auto [r0, n] : ops::rowChunks(engine, rows, {uint64_t(cx) * 4, uint64_t(cy) * 4}, op)) {
    const Tensor xc = x2.view(r0 * cx, {n, cx}), yc = y2.view(r0 * cy, {n, cy});
    std::vector<Arg> args = inPlace ? std::vector<Arg>{Arg::inout(xc)} : std::vector<Arg>{Arg::in(xc), Arg::out(yc)};
    args.push_back(Arg::in(weight.defined() ? weight : xc));  // placeholders are never read
    if (!rms) args.push_back(Arg::in(bias.defined() ? bias : xc));
    const NormPush push{uint32_t(n),     uint32_t(heads), uint32_t(dh), uint32_t(cx), uint32_t(xCol0),
                        uint32_t(cy),    uint32_t(yCol0), eps,          uint32_t(weightHeads)};
    const ops::Grid grid = ops::linearGrid(engine.caps(), ops::ceilDiv(uint64_t(n) * heads, g.linesPerGroup()), op);
    rec.dispatch(kernel, args, push, grid.x, grid.y, 1, op);
  }
}

void checkAffine(const Tensor& t, int64_t d, const std::string& op, const char* what) {
  if (!t.defined()) return;
  ops::requireF32(t, op, what);
  if (t.numel() != d)
    throw Error(op + ": " + what + " " + t.describe() + " should have " + std::to_string(d) + " values");
}

}  // namespace

void layerNorm(Recorder& rec, const Tensor& x, const Tensor& weight, const Tensor& bias, const Tensor& y, float eps) {
  const std::string op = "layerNorm";
  ops::requireF32(x, op, "x");
  ops::requireF32(y, op, "y");
  if (x.rank() < 1 || x.shape() != y.shape())
    throw Error(op + ": x " + x.describe() + " and y " + y.describe() + " must have one shape");
  const int64_t d = x.dim(-1);
  if (d == 0) throw Error(op + ": empty rows");
  checkAffine(weight, d, op, "weight");
  checkAffine(bias, d, op, "bias");
  const int64_t rows = x.numel() / d;
  normLines(rec, Norm::Layer, x.reshape({rows, d}), 0, y.reshape({rows, d}), 0, 1, d, weight, bias, eps, op);
}

void rmsNorm(Recorder& rec, const Tensor& x, const Tensor& weight, const Tensor& y, float eps) {
  const std::string op = "rmsNorm";
  ops::requireF32(x, op, "x");
  ops::requireF32(y, op, "y");
  ops::requireF32(weight, op, "weight");
  if (x.rank() < 1 || x.shape() != y.shape())
    throw Error(op + ": x " + x.describe() + " and y " + y.describe() + " must have one shape");
  const int64_t d = x.dim(-1), dh = weight.numel();
  if (dh == 0 || d % dh)
    throw Error(op + ": last dimension of " + x.describe() + " is not a multiple of weight " + weight.describe());
  const int64_t rows = x.numel() / d;
  normLines(rec, Norm::Rms, x.reshape({rows, d}), 0, y.reshape({rows, d}), 0, d / dh, dh, weight, Tensor(), eps, op);
}

void rmsNormHeads(Recorder& rec, const Tensor& x, int64_t xCol0, const Tensor& y, int64_t yCol0, int64_t heads,
                  const Tensor& weight, float eps) {
  const std::string op = "rmsNormHeads";
  ops::requireF32(x, op, "x");
  ops::requireF32(y, op, "y");
  ops::requireF32(weight, op, "weight");
  if (x.rank() < 1 || y.rank() < 1) throw Error(op + ": x and y need a column dimension");
  const int64_t cx = x.dim(-1), cy = y.dim(-1), dh = weight.rank() ? weight.dim(-1) : 0;
  const int64_t groups = dh ? weight.numel() / dh : 0;
  const int64_t rows = cx ? x.numel() / cx : 0;
  if (dh == 0 || heads < 0) throw Error(op + ": empty heads");
  if (weight.rank() > 2 || groups == 0 || heads % groups)
    throw Error(op + ": weight " + weight.describe() + " is not [dh] or [G, dh] with G dividing the " +
                std::to_string(heads) + " heads");
  if (rows != (cy ? y.numel() / cy : 0))
    throw Error(op + ": x " + x.describe() + " and y " + y.describe() + " have different rows");
  if (xCol0 < 0 || xCol0 + heads * dh > cx || yCol0 < 0 || yCol0 + heads * dh > cy)
    throw Error(op + ": " + std::to_string(heads) + " heads of " + std::to_string(dh) + " do not fit at columns " +
                std::to_string(xCol0) + " of " + x.describe() + " and " + std::to_string(yCol0) + " of " +
                y.describe());
  normLines(rec, Norm::Rms, x.reshape({rows, cx}), xCol0, y.reshape({rows, cy}), yCol0, heads, dh, weight, Tensor(),
            eps, op, groups > 1 ? heads / groups : 0);
}

}  // namespace spar
