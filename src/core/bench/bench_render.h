// The render column of `kdgrid bench` (BenchOptions::render): the whole Whitted render of a
// scene through one structure, paired pass by pass with the same render through the reference.
#pragma once

#include <cstdint>
#include <vector>

#include "accel/accelerator.h"
#include "bench/bench.h"
#include "scene/scene.h"

namespace kdgrid {

/// What the render column needs of a scene besides the structure: the scene, the bench's
/// camera, the reference (null while the reference itself is measured) and its image.
struct RenderJob {
  const Scene* scene = nullptr;
  Camera camera;
  const Accelerator* reference = nullptr;
  /// The reference's picture as written to PNG (8-bit sRGB): written while the reference is
  /// measured, compared with every other structure's.
  std::vector<uint8_t>* reference_image = nullptr;
};

/// Renders `reps` passes of one sample per pixel (width x height of `o`, pixel centres and the
/// same seed for every structure, shadows and the scene's reflections and refractions) through
/// `acc`, each after a pass through job.reference when there is one.
RenderFigures measure_render(const Accelerator& acc, const RenderJob& job, const BenchOptions& o);

}  // namespace kdgrid
