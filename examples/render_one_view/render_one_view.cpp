// Loads a SPAR model, encodes a few photos of a scene (cameras, motion masks), renders one new
// view from a given camera and writes it as a PNG: the smallest program on the installed
// library (include/spar/spar.h, linked as spar::spar).
//
//   render_one_view MODEL.spar OUT.png IMAGE [IMAGE ...]
//
// The camera: the first photo's estimated camera moved 5 % of the way towards the second one,
// with the first photo's intrinsics (cameras are in the first input's frame).
#include <spar/spar.h>

#include <cstdio>
#include <string>
#include <vector>

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: %s MODEL.spar OUT.png IMAGE [IMAGE ...]\n", argv[0]);
    return 2;
  }
  try {
    spar::Context context;  // the best Vulkan device (SPAR_DEVICE etc. from the environment)
    spar::Model model = spar::Model::open(argv[1]);
    const int h = int(model.imageHeight()), w = int(model.imageWidth());

    spar::Request request;
    for (int i = 3; i < argc; ++i) {
      const std::vector<float> image = spar::loadImage(argv[i], h, w);
      request.images.insert(request.images.end(), image.begin(), image.end());
      request.plan.inputs.push_back(i - 3);
    }
    request.plan.views = argc - 3;

    spar::Session session(context, model);
    const spar::Encoded& encoded = session.encode(request);

    // c2w of view i is encoded.c2w[16 i .. 16 i + 15], row-major; translation in column 3.
    spar::RenderCameras camera;
    std::array<float, 16> c2w{};
    for (int k = 0; k < 16; ++k) c2w[k] = encoded.c2w[k];
    if (request.plan.views > 1)
      for (int r = 0; r < 3; ++r) c2w[r * 4 + 3] += 0.05f * (encoded.c2w[16 + r * 4 + 3] - encoded.c2w[r * 4 + 3]);
    camera.c2w.push_back(c2w);
    camera.fxfycxcy.push_back({encoded.fxfycxcy[0], encoded.fxfycxcy[1], encoded.fxfycxcy[2], encoded.fxfycxcy[3]});

    const std::vector<float> rgb = session.render(camera);
    spar::writePng(argv[2], rgb, h, w);
    double gpuMs = 0;
    for (const spar::StageTime& s : session.stageTimes()) gpuMs += s.gpuMs;
    std::printf("%s: %dx%d view from %zu photos on %s (%.1f ms of GPU time)\n", argv[2], w, h, request.images.size() / (3 * size_t(h) * w),
                context.deviceName().c_str(), gpuMs);
    if (context.validationMessages() != 0) {
      std::fprintf(stderr, "render_one_view: %llu validation messages\n", (unsigned long long)context.validationMessages());
      return 1;
    }
    return 0;
  } catch (const spar::Error& e) {
    std::fprintf(stderr, "render_one_view: error: %s\n", e.what());
    return 1;
  }
}
