#include "viewer/gl_util.h"

#include <algorithm>
#include <cstdio>
#include <stdexcept>
#include <vector>

namespace kdgrid::viewer {

void check_gl_error(const char* call, const char* file, int line) {
  // Drain every queued error: GL may hold several flags at once.
  for (GLenum err = glGetError(); err != GL_NO_ERROR; err = glGetError())
    std::fprintf(stderr, "kdgrid-viewer: GL error 0x%04x in %s (%s:%d)\n", err, call, file, line);
}

namespace {

GLuint compile(const char* name, GLenum type, const char* src) {
  GLuint s = glCreateShader(type);
  GL_CHECK(glShaderSource(s, 1, &src, nullptr));
  GL_CHECK(glCompileShader(s));
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    GLint len = 0;
    glGetShaderiv(s, GL_INFO_LOG_LENGTH, &len);
    std::vector<char> log(size_t(std::max(len, 1)));
    glGetShaderInfoLog(s, len, nullptr, log.data());
    glDeleteShader(s);
    throw std::runtime_error(std::string("shader ") + name +
                             (type == GL_VERTEX_SHADER ? ".vert" : ".frag") +
                             " failed to compile: " + log.data());
  }
  return s;
}

}  // namespace

GLuint make_program(const char* name, const char* vertex_src, const char* fragment_src) {
  const GLuint vs = compile(name, GL_VERTEX_SHADER, vertex_src);
  const GLuint fs = compile(name, GL_FRAGMENT_SHADER, fragment_src);
  GLuint p = glCreateProgram();
  GL_CHECK(glAttachShader(p, vs));
  GL_CHECK(glAttachShader(p, fs));
  GL_CHECK(glLinkProgram(p));
  glDeleteShader(vs);
  glDeleteShader(fs);
  GLint ok = 0;
  glGetProgramiv(p, GL_LINK_STATUS, &ok);
  if (!ok) {
    GLint len = 0;
    glGetProgramiv(p, GL_INFO_LOG_LENGTH, &len);
    std::vector<char> log(size_t(std::max(len, 1)));
    glGetProgramInfoLog(p, len, nullptr, log.data());
    glDeleteProgram(p);
    throw std::runtime_error(std::string("shader program ") + name +
                             " failed to link: " + log.data());
  }
  return p;
}

}  // namespace kdgrid::viewer
