#include "accel/bvh.h"

#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <type_traits>

#include "accel/guards.h"
#include "util/cancel.h"
#include "util/error.h"

namespace kdgrid {

namespace {

/// Subtrees with more triangles than this are built as separate TBB tasks; below it the
/// task overhead outweighs the work.
constexpr uint32_t kParallelThreshold = 4096;
constexpr int kMaxBins = 256;

/// A SAH bin. Plain floats (Vec3 and Box3 initialise their members) so that a node's bin
/// array costs nothing until reset() is called for the k bins in use.
struct Bin {
  float lo[3], hi[3];
  uint32_t count;
  void reset() {
    for (int a = 0; a < 3; ++a) {
      lo[a] = kInf;
      hi[a] = -kInf;
    }
    count = 0;
  }
  void grow(const Box3& b) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], b.lo[a]);
      hi[a] = std::max(hi[a], b.hi[a]);
    }
    ++count;
  }
  Box3 box() const { return {{lo[0], lo[1], lo[2]}, {hi[0], hi[1], hi[2]}}; }
};
static_assert(std::is_trivially_default_constructible_v<Bin>);

/// Counters of one subtree, summed bottom-up so the totals do not depend on scheduling.
struct SubStats {
  uint64_t sah_evaluations = 0;
  uint64_t leaves = 0;
  uint32_t max_depth = 0;
  void add(const SubStats& o) {
    sah_evaluations += o.sah_evaluations;
    leaves += o.leaves;
    max_depth = std::max(max_depth, o.max_depth);
  }
};

class Builder {
 public:
  Builder(const Mesh& mesh, const BuildParams& p, std::vector<BvhNode>& slots,
          std::vector<uint32_t>& prims)
      : p_(p), slots_(slots), prims_(prims) {
    const size_t n = mesh.num_triangles();
    boxes_.resize(n);
    centroids_.resize(n);
    tbb::parallel_for(size_t(0), n, size_t(4096), [&](size_t i0) {
      for (size_t i = i0, e = std::min(n, i0 + 4096); i < e; ++i) {
        boxes_[i] = mesh.triangle_bounds(i);
        centroids_[i] = boxes_[i].center();
      }
    });
  }

  /// Builds the subtree over prims_[begin, end) into slots [slot, slot + 2n - 1).
  SubStats build(uint32_t slot, uint32_t begin, uint32_t end, int depth) {
    check_cancel(p_.cancel);
    SubStats st;
    st.max_depth = uint32_t(depth);
    const uint32_t n = end - begin;
    Box3 box, cbox;
    for (uint32_t i = begin; i < end; ++i) {
      box.grow(boxes_[prims_[i]]);
      cbox.grow(centroids_[prims_[i]]);
    }
    BvhNode& node = slots_[slot];
    node.lo = box.lo;
    node.hi = box.hi;

    auto make_leaf = [&] {
      node.offset = begin;
      node.count = n;
      st.leaves = 1;
      return st;
    };
    if (n <= 1 || depth >= Bvh::kMaxDepth - 1) return make_leaf();

    uint32_t mid = begin;
    const Vec3 ce = cbox.extent();
    if (!(ce.x > 0.0f) && !(ce.y > 0.0f) && !(ce.z > 0.0f)) {
      // All centroids coincide: no plane separates them, so halve the range by index.
      if (n <= uint32_t(p_.bvh_max_leaf)) return make_leaf();
      mid = begin + n / 2;
    } else {
      const int k = p_.bvh_bins;
      int best_axis = -1, best_bin = 0;
      // Costs are kept unnormalised (times the node area) so a flat box cannot divide by 0.
      float best_cost = kInf;
      // One pass over the triangles fills the bins of all three axes. Only the k bins in use
      // are initialised: clearing kMaxBins per node would dominate the build.
      Bin bins[3][kMaxBins];
      float lo[3], scale[3];
      for (int axis = 0; axis < 3; ++axis) {
        for (int b = 0; b < k; ++b) bins[axis][b].reset();
        lo[axis] = cbox.lo[axis];
        scale[axis] = ce[axis] > 0.0f ? float(k) * (1.0f - 1e-6f) / ce[axis] : 0.0f;
      }
      for (uint32_t i = begin; i < end; ++i) {
        const uint32_t prim = prims_[i];
        const Vec3& c = centroids_[prim];
        const Box3& pb = boxes_[prim];
        for (int axis = 0; axis < 3; ++axis) {
          Bin& bin = bins[axis][bin_of(c[axis], lo[axis], scale[axis], k)];
          bin.grow(pb);
        }
      }
      for (int axis = 0; axis < 3; ++axis) {
        if (!(ce[axis] > 0.0f)) continue;
        // Sweep from the right to get the area and count right of every boundary.
        float right_area[kMaxBins];
        uint32_t right_count[kMaxBins];
        Box3 acc;
        uint32_t cnt = 0;
        for (int b = k - 1; b > 0; --b) {
          acc.grow(bins[axis][b].box());
          cnt += bins[axis][b].count;
          right_area[b] = acc.area();
          right_count[b] = cnt;
        }
        acc = Box3();
        cnt = 0;
        for (int b = 0; b < k - 1; ++b) {
          acc.grow(bins[axis][b].box());
          cnt += bins[axis][b].count;
          ++st.sah_evaluations;
          if (cnt == 0 || right_count[b + 1] == 0) continue;
          const float cost =
              acc.area() * float(cnt) + right_area[b + 1] * float(right_count[b + 1]);
          if (cost < best_cost) {
            best_cost = cost;
            best_axis = axis;
            best_bin = b;
          }
        }
      }
      const float area = box.area();
      const float split_cost = p_.bvh_traversal_cost * area + best_cost;
      const float leaf_cost = float(n) * area;
      if (n <= uint32_t(p_.bvh_max_leaf) && !(split_cost < leaf_cost)) return make_leaf();
      if (best_axis >= 0) {
        const float blo = lo[best_axis], bscale = scale[best_axis];
        const auto it =
            std::partition(prims_.begin() + begin, prims_.begin() + end, [&](uint32_t prim) {
              return bin_of(centroids_[prim][best_axis], blo, bscale, k) <= best_bin;
            });
        mid = uint32_t(it - prims_.begin());
      }
      if (mid == begin || mid == end) {
        // Cannot happen with distinct centroids, but never build an empty child: fall back to
        // the object median along the widest centroid axis.
        const int axis = max_dimension(ce);
        mid = begin + n / 2;
        std::nth_element(prims_.begin() + begin, prims_.begin() + mid, prims_.begin() + end,
                         [&](uint32_t a, uint32_t b) {
                           return centroids_[a][axis] < centroids_[b][axis] ||
                                  (centroids_[a][axis] == centroids_[b][axis] && a < b);
                         });
      }
    }

    const uint32_t nl = mid - begin;
    const uint32_t left_slot = slot + 1, right_slot = slot + 2 * nl;
    node.offset = right_slot;
    node.count = BvhNode::kInner;
    SubStats sl, sr;
    if (n > kParallelThreshold) {
      // parallel_invoke rather than a task_group: when both halves throw (a cancel), a
      // task_group destroyed during the unwinding rethrows the other half's exception from its
      // destructor, which terminates the process.
      tbb::parallel_invoke([&] { sl = build(left_slot, begin, mid, depth + 1); },
                           [&] { sr = build(right_slot, mid, end, depth + 1); });
    } else {
      sl = build(left_slot, begin, mid, depth + 1);
      sr = build(right_slot, mid, end, depth + 1);
    }
    st.add(sl);
    st.add(sr);
    st.max_depth = std::max(sl.max_depth, sr.max_depth);
    return st;
  }

 private:
  static int bin_of(float c, float lo, float scale, int k) {
    const float f = (c - lo) * scale;
    // NaN and negatives go to bin 0, values at or past k (inf where a subnormal centroid
    // extent made the scale overflow) to bin k - 1; the cast only sees values in [0, k).
    if (!(f > 0.0f)) return 0;
    return f < float(k) ? std::min(int(f), k - 1) : k - 1;
  }

  const BuildParams& p_;
  std::vector<BvhNode>& slots_;
  std::vector<uint32_t>& prims_;
  std::vector<Box3> boxes_;
  std::vector<Vec3> centroids_;
};

}  // namespace

BuildStats Bvh::build(const Mesh& mesh, const BuildParams& params) {
  const auto t0 = std::chrono::steady_clock::now();
  if (params.bvh_bins < 2 || params.bvh_bins > kMaxBins)
    throw ParamError("bvh_bins = " + std::to_string(params.bvh_bins) + " is out of range: use 2.." +
                     std::to_string(kMaxBins) + " (default 16)");
  if (params.bvh_max_leaf < 1)
    throw ParamError("bvh_max_leaf = " + std::to_string(params.bvh_max_leaf) +
                     " must be >= 1 (default 8)");
  if (!(params.bvh_traversal_cost >= 0.0f) || !std::isfinite(params.bvh_traversal_cost))
    throw ParamError("bvh_traversal_cost must be a finite number >= 0 (default 1)");
  if (mesh.num_triangles() >= (size_t(1) << 31))
    throw ParamError("the BVH indexes triangles with 32 bits: split meshes above 2^31 triangles");

  // Memory guard, before any allocation. The peak is the binning phase: 2n-1 node slots,
  // a box and a centroid per triangle and the index list (the compacted nodes come after the
  // boxes are freed, and are smaller than them on every scene measured).
  const double nt = double(mesh.num_triangles());
  const uint64_t estimate = check_memory_budget(
      "bvh", mesh.num_triangles(),
      {{"node slots", 2.0 * nt * sizeof(BvhNode)},
       {"triangle boxes and centroids", nt * (sizeof(Box3) + sizeof(Vec3))},
       {"triangle indices", nt * sizeof(uint32_t)}},
      params,
      "the BVH needs about 104 bytes per triangle whatever its parameters: split the "
      "scene");

  mesh_ = &mesh;
  triangle_test_ = params.triangle_test;
  stats_ = {};
  stats_.peak_estimate = stats_.peak_expected = estimate;
  nodes_.clear();
  prims_.clear();
  const uint32_t n = uint32_t(mesh.num_triangles());

  SubStats st;
  if (n > 0) {
    // Every subtree over m triangles owns 2m-1 node slots (a binary tree with at most m
    // leaves), so parallel tasks write disjoint slots in a fixed depth-first layout; unused
    // slots are squeezed out afterwards.
    std::vector<BvhNode> slots(2 * size_t(n) - 1);
    prims_.resize(n);
    for (uint32_t i = 0; i < n; ++i) prims_[i] = i;
    tbb::task_arena arena(effective_threads(params.threads));
    arena.execute([&] {
      Builder b(mesh, params, slots, prims_);
      st = b.build(0, 0, n, 0);
    });
    // Compact in depth-first order: the left child stays right after its parent.
    nodes_.reserve(2 * st.leaves - 1);
    struct Item {
      uint32_t slot;
      int64_t patch;  // new index of the parent whose right-child offset points here, or -1
    };
    std::vector<Item> todo{{0, -1}};
    while (!todo.empty()) {
      const Item it = todo.back();
      todo.pop_back();
      const uint32_t idx = uint32_t(nodes_.size());
      if (it.patch >= 0) nodes_[size_t(it.patch)].offset = idx;
      const BvhNode& s = slots[it.slot];
      nodes_.push_back(s);
      if (!s.leaf()) {
        todo.push_back({s.offset, int64_t(idx)});  // right child, after the left subtree
        todo.push_back({it.slot + 1, -1});         // left child, next
      }
    }
  }

  stats_.nodes = nodes_.size();
  stats_.leaves = st.leaves;
  stats_.references = n;
  stats_.max_depth = st.max_depth;
  stats_.sah_evaluations = st.sah_evaluations;
  const uint64_t node_bytes = nodes_.size() * sizeof(BvhNode);
  const uint64_t prim_bytes = prims_.size() * sizeof(uint32_t);
  stats_.bytes = node_bytes + prim_bytes;
  stats_.bytes_by_part = {{"nodes", node_bytes}, {"prim indices", prim_bytes}};
  // SAH cost of the finished tree (traversal cost per inner node, 1 per triangle test),
  // relative to the root area: a build-quality figure to compare bin counts and leaf sizes.
  if (!nodes_.empty()) {
    double sah = 0.0;
    const double root_area = Box3(nodes_[0].lo, nodes_[0].hi).area();
    for (const BvhNode& nd : nodes_) {
      const double a = Box3(nd.lo, nd.hi).area();
      sah += a * (nd.leaf() ? double(nd.count) : double(params.bvh_traversal_cost));
    }
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.2f", root_area > 0 ? sah / root_area : 0.0);
    stats_.extra.push_back({"SAH cost", buf});
  }
  stats_.extra.push_back({"bins", std::to_string(params.bvh_bins)});
  stats_.extra.push_back({"max leaf", std::to_string(params.bvh_max_leaf)});
  stats_.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return stats_;
}

void Bvh::for_each_box(const std::function<void(const StructureBox&)>& fn) const {
  if (nodes_.empty()) return;
  std::vector<std::pair<uint32_t, int>> todo{{0, 0}};
  while (!todo.empty()) {
    const auto [i, d] = todo.back();
    todo.pop_back();
    const BvhNode& nd = nodes_[i];
    fn({Box3(nd.lo, nd.hi), d, nd.leaf(), nd.leaf() ? nd.count : 0});
    if (!nd.leaf()) {
      todo.push_back({nd.offset, d + 1});
      todo.push_back({i + 1, d + 1});
    }
  }
}

}  // namespace kdgrid
