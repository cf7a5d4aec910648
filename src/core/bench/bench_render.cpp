#include "bench/bench_render.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>

#include "bench/probes.h"
#include "render/renderer.h"

namespace kdgrid {

namespace {

using Clock = std::chrono::steady_clock;

/// A channel differs visibly when it moves by more than one step of an 8-bit display (relative
/// above 1): other structures report the same triangles with barycentrics rounded otherwise,
/// which moves interpolated normals, and so colours, in their last bits.
constexpr float kVisibleDifference = 1.0f / 255.0f;

/// One pass of `r` from scratch; its wall time in seconds.
double timed_pass(Renderer& r) {
  r.reset();
  const auto t0 = Clock::now();
  r.render_pass();
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

}  // namespace

RenderFigures measure_render(const Accelerator& acc, const RenderJob& job, const BenchOptions& o) {
  RenderSettings rs;
  rs.width = o.width;
  rs.height = o.height;
  rs.jitter = false;  // pixel centres: the primary rays are the bench's primary set
  Renderer mine(*job.scene, acc, rs);
  mine.set_camera(job.camera);
  std::unique_ptr<Renderer> theirs;
  if (job.reference) {
    theirs = std::make_unique<Renderer>(*job.scene, *job.reference, rs);
    theirs->set_camera(job.camera);
  }
  RenderFigures f;
  f.measured = true;
  std::vector<double> ratios, reference_reps;
  for (int rep = 0; rep < o.reps; ++rep) {
    if (theirs) reference_reps.push_back(timed_pass(*theirs));
    f.seconds_reps.push_back(timed_pass(mine));
    if (theirs && f.seconds_reps.back() > 0)
      ratios.push_back(reference_reps.back() / f.seconds_reps.back());
  }
  const RenderCounters& c = mine.counters();
  f.primary = c.primary;
  f.shadow = c.shadow;
  f.reflection = c.reflection;
  f.refraction = c.refraction;
  f.seconds_median = median(f.seconds_reps);
  f.mrays_median = f.seconds_median > 0 ? double(f.rays()) / f.seconds_median * 1e-6 : 0.0;
  f.ratio_to_reference = theirs ? median(ratios) : 1.0;
  f.reference_seconds = theirs ? median(reference_reps) : f.seconds_median;

  std::vector<float> image;
  mine.resolve(image);
  if (!theirs) {
    if (job.reference_image) *job.reference_image = std::move(image);
    f.pixels_differ = 0;
  } else if (job.reference_image && job.reference_image->size() == image.size()) {
    const std::vector<float>& ref = *job.reference_image;
    f.pixels_differ = 0;
    for (size_t p = 0; p + 2 < image.size(); p += 3) {
      bool differ = false;
      for (size_t ch = p; ch < p + 3; ++ch)
        differ |= std::fabs(image[ch] - ref[ch]) >
                  kVisibleDifference * std::max(1.0f, std::fabs(ref[ch]));
      f.pixels_differ += differ;
    }
  }
  return f;
}

}  // namespace kdgrid
