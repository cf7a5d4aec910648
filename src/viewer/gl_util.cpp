#include "viewer/gl_util.h"

#include <algorithm>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <vector>

namespace kdgrid::viewer {

void check_gl_error(const char* call, const char* file, int line) {
  // Drain every queued error: GL may hold several flags at once.
  for (GLenum err = glGetError(); err != GL_NO_ERROR; err = glGetError())
    std::fprintf(stderr, "kdgrid-viewer: GL error 0x%04x in %s (%s:%d)\n", err, call, file, line);
}

namespace {

/// The info log of a shader or program, read with its glGet*iv and glGet*InfoLog.
template <class GetIv, class GetLog>
std::string info_log(GLuint object, GetIv get_iv, GetLog get_log) {
  GLint len = 0;
  get_iv(object, GL_INFO_LOG_LENGTH, &len);
  std::vector<char> log(size_t(std::max(len, 1)));
  get_log(object, len, nullptr, log.data());
  return log.data();
}

GLuint compile(const char* name, GLenum type, const char* src) {
  GLuint s = glCreateShader(type);
  GL_CHECK(glShaderSource(s, 1, &src, nullptr));
  GL_CHECK(glCompileShader(s));
  GLint ok = 0;
  glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
  if (!ok) {
    const std::string log = info_log(s, glGetShaderiv, glGetShaderInfoLog);
    glDeleteShader(s);
    throw std::runtime_error(std::string("shader ") + name +
                             (type == GL_VERTEX_SHADER ? ".vert" : ".frag") +
                             " failed to compile: " + log);
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
    const std::string log = info_log(p, glGetProgramiv, glGetProgramInfoLog);
    glDeleteProgram(p);
    throw std::runtime_error(std::string("shader program ") + name + " failed to link: " + log);
  }
  return p;
}

void draw_fullscreen(GLuint program, const char* sampler, GLuint texture, GLuint vao) {
  GL_CHECK(glUseProgram(program));
  GL_CHECK(glActiveTexture(GL_TEXTURE0));
  GL_CHECK(glBindTexture(GL_TEXTURE_2D, texture));
  GL_CHECK(glUniform1i(glGetUniformLocation(program, sampler), 0));
  GL_CHECK(glBindVertexArray(vao));
  GL_CHECK(glDrawArrays(GL_TRIANGLES, 0, 6));
  GL_CHECK(glBindVertexArray(0));
}

}  // namespace kdgrid::viewer
