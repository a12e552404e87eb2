#include "model/stages/select_views.h"

#include "engine/engine.h"
#include "engine/ops/copy2d.h"

namespace spar::stages {

Tensor selectViews(Recorder& rec, const Tensor& all, const std::vector<int64_t>& positions, int64_t perView,
                   const Shape& viewShape) {
  Shape shape{int64_t(positions.size())};
  shape.insert(shape.end(), viewShape.begin(), viewShape.end());
  const Tensor out = rec.engine().tensor(shape);
  for (size_t j = 0; j < positions.size(); ++j)
    copy2d(rec, all.view(positions[j] * perView, {1, perView}), perView, 0, out.view(int64_t(j) * perView, {1, perView}),
           perView, 0, 1, perView);
  return out;
}

}  // namespace spar::stages
