// Small OpenGL helpers for the viewer: error checking, shader programs.
#pragma once

#include <epoxy/gl.h>

#include <string>

namespace kdgrid::viewer {

/// Logs (once per call site and error code) any pending GL error with the call that raised it.
void check_gl_error(const char* call, const char* file, int line);

/// Wraps a GL call and reports errors it raised (pbrt's GL_CHECK). Cheap enough to keep in
/// release builds: glGetError is a query the driver answers without a round trip.
#define GL_CHECK(call)                                           \
  do {                                                           \
    call;                                                        \
    ::kdgrid::viewer::check_gl_error(#call, __FILE__, __LINE__); \
  } while (0)

/// Compiles and links a program from vertex and fragment source. Throws std::runtime_error
/// with the driver's log and the shader's name on failure.
/// Draws the full-screen pair of triangles of shaders/image.vert with `program`, `texture`
/// bound to its sampler `sampler` (texture unit 0) and `vao` an empty vertex array.
void draw_fullscreen(GLuint program, const char* sampler, GLuint texture, GLuint vao);

GLuint make_program(const char* name, const char* vertex_src, const char* fragment_src);

}  // namespace kdgrid::viewer
