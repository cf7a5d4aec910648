// The hybrid's introspection for tests and the viewer: leaf boxes, split planes, the cell
// map's size in either form. The build is build.cpp, the walk walk.h.
#include "accel/hybrid/hybrid.h"

#include <vector>

namespace kdgrid {

uint64_t GridKdHybrid::matrix_bytes(bool dense) const {
  if (dense) return hybrid::DenseCellMap::bytes_for(dims_);
  return map_.bricked().bytes(nodes_);
}

Box3 GridKdHybrid::step_box(uint32_t leaf) const {
  const Leaf& l = leaves_[leaf];
  Box3 b;
  for (int a = 0; a < 3; ++a) {
    b.lo[a] = float(origin_[a] + l.lo[a] * cell_);
    b.hi[a] = float(origin_[a] + l.hi[a] * cell_);
  }
  return b;
}

void GridKdHybrid::for_each_split(const std::function<void(const SplitPlane&)>& fn) const {
  if (nodes_.empty()) return;
  struct Item {
    uint32_t node;
    int32_t lo[3], hi[3];
    int depth;
  };
  std::vector<Item> stack;
  stack.push_back({0, {0, 0, 0}, {dims_[0], dims_[1], dims_[2]}, 0});
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    const Node& n = nodes_[it.node];
    if (n.axis == 3) continue;
    SplitPlane sp;
    sp.axis = int(n.axis);
    sp.position = float(origin_[n.axis] + double(n.split) * cell_);
    for (int a = 0; a < 3; ++a) {
      sp.node_box.lo[a] = float(origin_[a] + double(it.lo[a]) * cell_);
      sp.node_box.hi[a] = float(origin_[a] + double(it.hi[a]) * cell_);
    }
    sp.depth = it.depth;
    fn(sp);
    Item l = it, r = it;
    l.node = it.node + 1;
    l.hi[n.axis] = n.split;
    r.node = n.right;
    r.lo[n.axis] = n.split;
    l.depth = r.depth = it.depth + 1;
    stack.push_back(r);  // left popped first: depth-first, left before right
    stack.push_back(l);
  }
}

void GridKdHybrid::for_each_box(const std::function<void(const StructureBox&)>& fn) const {
  for (uint32_t i = 0; i < leaves_.size(); ++i)
    if (leaves_[i].count)
      fn({step_box(i), int(leaf_depth_[i]), true, leaves_[i].count & ~kSubtreeFlag});
}

}  // namespace kdgrid
