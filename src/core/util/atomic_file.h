// Every file kdgrid writes (images, scenes, .rays/.hits, JSON/Markdown/CSV reports) goes
// through AtomicFile: the bytes go to a hidden temporary file beside the target
// (".NAME.tmp-PID-N.EXT", same folder so the rename cannot cross filesystems), every write
// and the close are checked, the data is fsync'd, and only then is the temporary renamed over
// the target. A full disk, a file-size limit (ulimit -f) or an error therefore leaves the old
// file as it was and ends in an Error naming the path and the cause; SIGINT, SIGTERM and
// SIGHUP arriving while a temporary exists remove it before the process dies. (SIGKILL cannot
// be caught: it may leave a hidden temporary, never a truncated target.)
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace kdgrid {

class AtomicFile {
 public:
  /// Creates the temporary beside `path`; Error if the folder is missing or not writable.
  explicit AtomicFile(const std::string& path);
  /// Removes the temporary unless commit() succeeded.
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  /// Appends bytes (buffered); Error naming the path and errno's text on failure.
  void write(const void* data, size_t size);
  void write(std::string_view s) { write(s.data(), s.size()); }
  /// Bytes written so far.
  size_t size() const { return written_ + buffer_.size(); }
  /// Flushes, fsyncs and closes the temporary (all checked), renames it over the target and
  /// fsyncs the folder. Error on any failure (the temporary is removed, the target untouched).
  void commit();

  const std::string& path() const { return path_; }
  const std::string& temp_path() const { return temp_; }

 private:
  void flush();
  [[noreturn]] void fail(const std::string& what, int err);

  std::string path_, temp_;
  int fd_ = -1;
  int slot_ = -1;  ///< entry in the signal handler's list of temporaries
  size_t written_ = 0;
  std::vector<char> buffer_;
  bool committed_ = false;
};

/// Writes `bytes` to `path` through an AtomicFile.
void write_file_atomically(const std::string& path, std::string_view bytes);

/// Checks an output path before any work is done, so a bad -o fails in milliseconds instead of
/// after a render or a build. ParamError (naming `option`, e.g. "-o") when:
///  - the path is an existing directory or another non-regular file (a FIFO, a device);
///  - its folder does not exist or is not writable;
///  - its extension (compared without case) is not one of `extensions` (e.g. {".png", ".exr"};
///    empty = any), since the contents would not match what the name says;
///  - it is the same file as one of `inputs` (std::filesystem::equivalent, so links and
///    "./a" vs "a" are caught): writing it would destroy the input.
void check_output_path(const std::string& path, const std::string& option,
                       const std::vector<std::string>& extensions,
                       const std::vector<std::string>& inputs = {});

/// errno's text for a failed write, in words a user acts on ("no space left on the device",
/// "file too large (the file-size limit, ulimit -f, was reached)", ...).
std::string write_error_text(int err);

/// The extension of `path` in lower case, with its dot ("" if none).
std::string lower_extension(const std::string& path);

}  // namespace kdgrid
