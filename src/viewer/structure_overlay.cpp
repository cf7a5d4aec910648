// kdgrid-viewer's structure overlay (split planes, cells, boxes): built off the UI thread from
// the shown structure and the overlay settings, then handed to the LineRenderer (overlay.h).
#include <algorithm>
#include <array>
#include <optional>

#include "viewer/viewer.h"
#include "viewer/viewer_internal.h"

namespace kdgrid::viewer {

void Viewer::rebuild_structure_overlay() {
  // Built off the UI thread (a BVH over the full dragon is 1.7M boxes): a newer request waits
  // for the running one and replaces its result; the old lines stay on screen meanwhile.
  if (overlay_job_.valid()) return;
  overlay_dirty_ = false;
  const std::shared_ptr<const World> w = world_;
  const bool splits = show_splits_ && (!splits_of_pick_ || pick_), cells = show_cells_,
             boxes = show_boxes_;
  const std::optional<RaySegment> seg =
      splits_of_pick_ && pick_ ? std::optional<RaySegment>(pick_->segment) : std::nullopt;
  const std::array<int, 4> depths = {split_depth_[0], split_depth_[1], box_depth_[0],
                                     box_depth_[1]};
  overlay_job_ = run_in_background([=] {
    OverlayResult r;
    if (w) {
      const Accelerator& a = *w->accel;
      if (splits)
        r.items += build_split_overlay(a, depths[0], depths[1], r.batch, seg ? &*seg : nullptr);
      if (cells) r.items += build_cell_overlay(a, r.batch, &r.wanted);
      if (boxes) r.items += build_box_overlay(a, depths[2], depths[3], r.batch, &r.wanted);
    }
    return r;
  });
}

void Viewer::poll_structure_overlay() {
  if (structure_lines_.uploading()) {
    const size_t sent = structure_lines_.upload_step(kUploadVerticesPerFrame);
    overlay_frames_.max_uploaded = std::max(overlay_frames_.max_uploaded, sent);
    overlay_frames_.uploaded += sent;
    ++overlay_frames_.upload_frames;
  }
  if (!overlay_job_.ready()) return;
  OverlayResult r = overlay_job_.get();
  if (overlay_dirty_) return;  // settings changed meanwhile: the next build replaces it
  overlay_items_ = r.items;
  overlay_wanted_ = r.wanted;
  structure_lines_.upload(std::move(r.batch));
}

}  // namespace kdgrid::viewer
