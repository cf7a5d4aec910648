#include "bench/bench_render.h"

#include <cmath>
#include <cstdint>
#include <memory>

#include "bench/probes.h"
#include "image/image_io.h"
#include "render/renderer.h"

namespace kdgrid {

namespace {

/// One pass of `r` from scratch; its wall time in seconds (Renderer::seconds()).
double timed_pass(Renderer& r) {
  r.reset();
  r.render_pass();
  return r.seconds();
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

  // The pictures as written to PNG, compared as `kdgrid sweep scale` compares its renders.
  std::vector<float> rgb;
  mine.resolve(rgb);
  std::vector<uint8_t> image;
  tonemap_srgb8(rgb, image);
  if (!theirs) {
    if (job.reference_image) *job.reference_image = std::move(image);
    f.pixels_differ = 0;
  } else if (job.reference_image) {
    const double fraction = srgb8_difference(image, *job.reference_image).pixels_differing;
    f.pixels_differ = std::llround(fraction * double(o.width) * double(o.height));
  }
  return f;
}

}  // namespace kdgrid
