#include <chrono>
#include <new>

#include "accel/accelerator.h"
#include "accel/brute.h"
#include "accel/bvh.h"
#include "accel/embree.h"
#include "accel/grid.h"
#include "accel/guards.h"
#include "accel/hybrid/hybrid.h"
#include "accel/irregular.h"
#include "accel/kdtree.h"
#include "util/error.h"

namespace kdgrid {

std::vector<std::string> accelerator_names() {
  std::vector<std::string> names = {"brute", "bvh", "kdtree", "grid", "hybrid", "irregular"};
  for (const EmbreeConfig& c : embree_configs()) names.push_back(c.name);
  return names;
}

bool is_embree(const std::string& name) {
  return embree_config(name) != nullptr;
}

std::unique_ptr<Accelerator> make_accelerator(const std::string& name) {
  if (name == "brute") return std::make_unique<BruteForce>();
  if (name == "bvh") return std::make_unique<Bvh>();
  if (name == "kdtree") return std::make_unique<KdTree>();
  if (name == "grid") return std::make_unique<UniformGrid>();
  if (name == "hybrid") return std::make_unique<GridKdHybrid>();
  if (name == "irregular") return std::make_unique<IrregularGrid>();
  if (const EmbreeConfig* c = embree_config(name)) return std::make_unique<EmbreeAccel>(*c);
  std::string valid;
  for (const auto& n : accelerator_names()) valid += (valid.empty() ? "" : ", ") + n;
  throw ParamError("unknown accelerator '" + name + "': choose one of " + valid);
}

std::unique_ptr<Accelerator> build_accelerator(const std::string& name, const Mesh& mesh,
                                               const BuildParams& params) {
  auto a = make_accelerator(name);
  try {
    a->build(mesh, params);
  } catch (const std::bad_alloc&) {
    // An estimate below the budget can still meet a smaller real limit (a cgroup or ulimit
    // tightened since, other processes): say what ran out instead of "std::bad_alloc".
    throw_build_out_of_memory(name, mesh.num_triangles(), params);
  }
  return a;
}

}  // namespace kdgrid
