// kdgrid-viewer's input: the GLFW key, mouse, scroll, cursor and drop callbacks, the keys
// held down for ImGui across a frame, and the camera moves of held keys. ImGui sees input
// first; the camera reacts only to what it does not capture (docs/DESIGN.md, "The viewer").
#include <epoxy/gl.h>
#define GLFW_INCLUDE_NONE
#include <GLFW/glfw3.h>
#include <imgui.h>

#include <cmath>
#include <cstdio>

#include "viewer/viewer.h"

namespace kdgrid::viewer {

void Viewer::print_camera() {
  message_ = cam_.cli_flags();
  std::printf("%s\n", message_.c_str());
  std::fflush(stdout);
}

void Viewer::on_key(int key, int /*scancode*/, int action, int mods) {
  note_input();
  // ImGui 1.86 reads a key's state once per frame, so a press and its release within one
  // frame would never reach it (a short Enter in a text field on a slow frame was lost): such
  // a key is held down through one frame (hold_short_presses).
  if (action == GLFW_PRESS && key >= 0) pressed_this_frame_.insert(key);
  if (action == GLFW_RELEASE && pressed_this_frame_.count(key)) short_presses_.insert(key);
  if (action != GLFW_PRESS) return;
  // Ctrl+Q and Esc work wherever the keyboard focus is, a panel's text field included.
  if (key == GLFW_KEY_Q && (mods & GLFW_MOD_CONTROL)) {
    // Ctrl+Q quits (plain Q is "down"); a --hold run then finishes like a closed window.
    glfwSetWindowShouldClose(window_, GLFW_TRUE);
    if (end_reason_.empty()) end_reason_ = "ctrl+q";
    cancel_task();  // a running build stops rather than delaying the exit
    return;
  }
  if (key == GLFW_KEY_ESCAPE) {
    // Cancels the running build; its old structure stays. The start-up scene's first build
    // has none, so it is not cancelled (Ctrl+Q quits). In a text field Esc also drops the
    // edit (ImGui restores the value), and the panel must not take that as a new request.
    escape_this_frame_ = true;
    if (world_) cancel_task();
    return;
  }
  if (ImGui::GetIO().WantCaptureKeyboard) return;
  switch (key) {
    case GLFW_KEY_TAB:
      cam_.toggle_mode();
      break;
    case GLFW_KEY_HOME:
      cam_.frame_scene();
      break;
    case GLFW_KEY_C:
      print_camera();
      break;
    case GLFW_KEY_EQUAL:
    case GLFW_KEY_KP_ADD:
      cam_.scale_speed(1.25f);
      break;
    case GLFW_KEY_MINUS:
    case GLFW_KEY_KP_SUBTRACT:
      cam_.scale_speed(1.0f / 1.25f);
      break;
    case GLFW_KEY_F12:
    case GLFW_KEY_P:
      save_screenshot(default_output_name("kdgrid-screenshot", "png"));
      break;
    case GLFW_KEY_H:
      opts_.hide_ui = !opts_.hide_ui;  // the picture alone, as a screenshot with --hide-ui
      break;
    case GLFW_KEY_F1:
      show_keys_ = !show_keys_;
      break;
    case GLFW_KEY_F:
      frame_pick();
      break;
    case GLFW_KEY_R:
      reset_layout_ = true;
      break;
    case GLFW_KEY_L:
      // auto -> lights -> eye light -> normals -> auto
      shading_choice_ = ShadingChoice((int(shading_choice_) + 1) % 4);
      break;
    default:
      break;
  }
}

void Viewer::hold_short_presses() {
  ImGuiIO& io = ImGui::GetIO();
  for (int k : short_presses_)
    if (k < int(IM_ARRAYSIZE(io.KeysDown))) {
      io.KeysDown[k] = true;  // ImGui sees the key down in this frame...
      held_keys_.insert(k);
    }
  short_presses_.clear();
  pressed_this_frame_.clear();
}

void Viewer::release_held_keys() {
  ImGuiIO& io = ImGui::GetIO();
  for (int k : held_keys_)  // ...and released in the next, unless it is down again
    if (glfwGetKey(window_, k) != GLFW_PRESS) io.KeysDown[k] = false;
  held_keys_.clear();
  escape_this_frame_ = false;
}

void Viewer::on_mouse_button(int button, int action, int mods) {
  note_input();
  const double x = cursor_x_, y = cursor_y_;
  if (action == GLFW_PRESS) {
    if (ImGui::GetIO().WantCaptureMouse) return;
    if (button == GLFW_MOUSE_BUTTON_LEFT) {
      if (mods & GLFW_MOD_CONTROL) {
        left_down_ = false;
        int ww, wh;
        glfwGetWindowSize(window_, &ww, &wh);
        if (ww > 0 && wh > 0) do_pick(int(x / ww * posted_w_), int(y / wh * posted_h_));
        return;
      }
      left_down_ = true;
      dragged_ = false;
      press_x_ = x;
      press_y_ = y;
    } else if (button == GLFW_MOUSE_BUTTON_RIGHT) {
      right_down_ = true;
    }
  } else if (action == GLFW_RELEASE) {
    if (button == GLFW_MOUSE_BUTTON_LEFT && left_down_) {
      left_down_ = false;
      if (!dragged_) {
        // Window coordinates to image pixels (the image fills the window).
        int ww, wh;
        glfwGetWindowSize(window_, &ww, &wh);
        if (ww > 0 && wh > 0) do_pick(int(x / ww * posted_w_), int(y / wh * posted_h_));
      }
    } else if (button == GLFW_MOUSE_BUTTON_RIGHT) {
      right_down_ = false;
    }
  }
}

void Viewer::on_scroll(double /*dx*/, double dy) {
  note_input();
  if (ImGui::GetIO().WantCaptureMouse) return;
  cam_.dolly(float(dy));
}

void Viewer::on_cursor_pos(double x, double y) {
  note_input();
  const double dx = x - cursor_x_, dy = y - cursor_y_;
  cursor_x_ = x;
  cursor_y_ = y;
  if (left_down_) {
    if (dragged_) {
      cam_.orbit(-float(dx) * kRadPerPixel, float(dy) * kRadPerPixel);
    } else if (std::hypot(x - press_x_, y - press_y_) > 3.0) {
      // A press that moves less than 3 units is a click (pick). Past that it is a drag, and
      // the motion since the press counts, so the orbit follows the cursor exactly.
      dragged_ = true;
      cam_.orbit(-float(x - press_x_) * kRadPerPixel, float(y - press_y_) * kRadPerPixel);
    }
  }
  if (right_down_ && (dx != 0 || dy != 0))
    cam_.look(-float(dx) * kRadPerPixel, -float(dy) * kRadPerPixel);
}

void Viewer::on_drop(int count, const char** paths) {
  note_input();
  if (count > 0) start_load(paths[0]);
}

void Viewer::note_input() {
  // ImGui updates hover and active state in the frame after an event, and shows the result of
  // a click in the one after that.
  settle_frames_ = 3;
}

bool Viewer::wants_continuous_frames() const {
  // A coarse preview is showing: keep drawing until the full resolution has been posted.
  if (settle_frames_ > 0 || glfwWindowShouldClose(window_) || posted_preview_) return true;
  if (ImGui::GetCurrentContext() && (ImGui::GetIO().WantTextInput || ImGui::IsAnyItemActive()))
    return true;
  // An overlay goes up, and into its picture, a part per frame.
  if (structure_lines_.uploading() || structure_lines_.drawing()) return true;
  // Held keys move the camera every frame without sending events.
  for (int k : {GLFW_KEY_W, GLFW_KEY_A, GLFW_KEY_S, GLFW_KEY_D, GLFW_KEY_Q, GLFW_KEY_E})
    if (glfwGetKey(window_, k) == GLFW_PRESS) return true;
  // A scripted --frames run counts frames: give it them at the capped rate.
  return opts_.frames > 0 && frame_count_ < opts_.frames;
}

void Viewer::handle_continuous_input(float dt) {
  if (ImGui::GetIO().WantCaptureKeyboard || glfwWindowShouldClose(window_)) return;
  const auto down = [&](int k) { return glfwGetKey(window_, k) == GLFW_PRESS ? 1.0f : 0.0f; };
  // Ctrl+letter is a shortcut (Ctrl+Q quits), not a move.
  if (down(GLFW_KEY_LEFT_CONTROL) + down(GLFW_KEY_RIGHT_CONTROL) > 0) return;
  const float right = down(GLFW_KEY_D) - down(GLFW_KEY_A);
  const float up = down(GLFW_KEY_E) - down(GLFW_KEY_Q);
  const float fwd = down(GLFW_KEY_W) - down(GLFW_KEY_S);
  if (right != 0 || up != 0 || fwd != 0) {
    const float boost = (down(GLFW_KEY_LEFT_SHIFT) + down(GLFW_KEY_RIGHT_SHIFT)) > 0 ? 4.0f : 1.0f;
    cam_.move(right, up, fwd, dt * boost);
  }
}

}  // namespace kdgrid::viewer
