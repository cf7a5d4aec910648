#include "util/atomic_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <climits>
#include <csignal>
#include <cstring>
#include <filesystem>
#include <mutex>

#include "util/error.h"

namespace kdgrid {

namespace fs = std::filesystem;

namespace {

// ---- temporaries removed by the signal handler ----
// Fixed storage, because a signal handler may only call async-signal-safe functions: it walks
// these slots and unlink()s the names of those in use.
constexpr int kSlots = 16;
constexpr size_t kMaxTempPath = 4096;
char g_temp_names[kSlots][kMaxTempPath];
std::atomic<bool> g_slot_used[kSlots];
std::mutex g_slots_mutex;  // guards registration and the handler installation below
int g_registered = 0;      // slots in use
constexpr int kSignals[] = {SIGINT, SIGTERM, SIGHUP};
struct sigaction g_old_actions[3];
bool g_installed[3] = {false, false, false};

extern "C" void remove_temporaries_and_die(int sig) {
  for (int i = 0; i < kSlots; ++i)
    if (g_slot_used[i].load()) ::unlink(g_temp_names[i]);
  // Die of the same signal, as the process would have without this handler.
  ::signal(sig, SIG_DFL);
  ::raise(sig);
}

int register_temporary(const std::string& name) {
  if (name.size() >= kMaxTempPath) return -1;
  std::lock_guard<std::mutex> lock(g_slots_mutex);
  for (int i = 0; i < kSlots; ++i) {
    if (g_slot_used[i].load()) continue;
    std::memcpy(g_temp_names[i], name.c_str(), name.size() + 1);
    g_slot_used[i].store(true);
    if (g_registered++ == 0) {
      // Take over only signals that would kill the process anyway (default action): a
      // handler someone installed (the render's Ctrl-C that keeps the finished passes) and an
      // ignored signal (nohup) stay as they are.
      for (int s = 0; s < 3; ++s) {
        struct sigaction old {};
        if (::sigaction(kSignals[s], nullptr, &old) != 0 || old.sa_handler != SIG_DFL) continue;
        struct sigaction act {};
        act.sa_handler = remove_temporaries_and_die;
        sigemptyset(&act.sa_mask);
        if (::sigaction(kSignals[s], &act, &g_old_actions[s]) == 0) g_installed[s] = true;
      }
    }
    return i;
  }
  return -1;  // more than kSlots files at once: the file is still written safely, only a
              // signal may then leave its hidden temporary behind
}

void unregister_temporary(int slot) {
  if (slot < 0) return;
  std::lock_guard<std::mutex> lock(g_slots_mutex);
  g_slot_used[slot].store(false);
  if (--g_registered == 0)
    for (int s = 0; s < 3; ++s)
      if (g_installed[s]) {
        ::sigaction(kSignals[s], &g_old_actions[s], nullptr);
        g_installed[s] = false;
      }
}

}  // namespace

std::string write_error_text(int err) {
  if (err == EFBIG) return "file too large (the file-size limit, ulimit -f, was reached)";
  if (err == ENOSPC) return "no space left on the device";
  if (err == EDQUOT) return "disk quota exceeded";
  return std::strerror(err);
}

namespace {

constexpr size_t kBufferBytes = size_t(1) << 20;

fs::path folder_of(const fs::path& target) {
  const fs::path dir = target.parent_path();
  return dir.empty() ? fs::path(".") : dir;
}

/// The longest file name the file system holding `dir` takes (NAME_MAX where it cannot say).
size_t max_name_bytes(const fs::path& dir) {
  const long n = ::pathconf(dir.c_str(), _PC_NAME_MAX);
  return n > 0 ? size_t(n) : size_t(NAME_MAX);
}

/// The hidden temporary beside `target`: ".STEM" + `tag` + ".EXT". Where that would be longer
/// than a file name may be (a valid target name of up to NAME_MAX bytes plus the tag) or would
/// make the path longer than PATH_MAX, the stem is shortened (never inside a UTF-8 character)
/// and the extension dropped if it must be: the tag, unique to this process and file, keeps
/// the name unique, the rest only tells a person whose temporary it is.
std::string temp_path_for(const fs::path& target, const std::string& tag) {
  const fs::path dir = target.parent_path();
  const std::string stem = target.stem().string();
  std::string ext = target.extension().string();
  size_t room = max_name_bytes(folder_of(target));
  const size_t dir_bytes = dir.empty() ? 0 : dir.string().size() + 1;
  room = std::min(room, dir_bytes + 1 < size_t(PATH_MAX) ? size_t(PATH_MAX) - 1 - dir_bytes : 0);
  if (1 + tag.size() + ext.size() > room) ext.clear();
  size_t keep = 1 + tag.size() + ext.size() > room ? 0 : room - 1 - tag.size() - ext.size();
  if (keep < stem.size())
    while (keep > 0 && (static_cast<unsigned char>(stem[keep]) & 0xC0) == 0x80) --keep;
  std::string name = ".";  // built stepwise: GCC 12 warns falsely on "." + std::string
  name += stem.substr(0, std::min(keep, stem.size()));
  name += tag;
  name += ext;
  return (dir / name).string();
}

}  // namespace

std::string lower_extension(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return char(std::tolower(c)); });
  return ext;
}

AtomicFile::AtomicFile(const std::string& path) : path_(path) {
  // A write past the file-size limit raises SIGXFSZ, whose default action kills the process
  // before the failed write can be reported; ignored, the write fails with EFBIG instead.
  static const bool xfsz_ignored = [] {
    ::signal(SIGXFSZ, SIG_IGN);
    return true;
  }();
  (void)xfsz_ignored;
  static std::atomic<unsigned> counter{0};
  const fs::path target(path);
  temp_ =
      temp_path_for(target, ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter++));
  slot_ = register_temporary(temp_);
  fd_ = ::open(temp_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
  if (fd_ < 0) {
    const int err = errno;
    unregister_temporary(slot_);
    slot_ = -1;
    const fs::path dir = folder_of(target);
    if (err == ENAMETOOLONG)
      throw Error(path + ": cannot create a file in '" + dir.string() +
                  "': the path is too long (" + std::to_string(temp_.size()) +
                  " bytes with the temporary's name); write to a folder with a shorter path");
    throw Error(path + ": cannot create a file in '" + dir.string() + "' (" +
                write_error_text(err) + "); check that the folder exists and is writable");
  }
  buffer_.reserve(kBufferBytes);
}

AtomicFile::~AtomicFile() {
  if (fd_ >= 0) ::close(fd_);
  if (!committed_) ::unlink(temp_.c_str());
  unregister_temporary(slot_);
}

void AtomicFile::fail(const std::string& what, int err) {
  if (fd_ >= 0) ::close(fd_);
  fd_ = -1;
  ::unlink(temp_.c_str());
  throw Error(path_ + ": " + what + " failed after " + std::to_string(written_) +
              " bytes: " + write_error_text(err) +
              "; the file was not changed (free space or raise the limit, "
              "then run again)");
}

void AtomicFile::flush() {
  const char* p = buffer_.data();
  size_t left = buffer_.size();
  while (left > 0) {
    const ssize_t n = ::write(fd_, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      fail("writing", errno);
    }
    p += n;
    left -= size_t(n);
    written_ += size_t(n);
  }
  buffer_.clear();
}

void AtomicFile::write(const void* data, size_t size) {
  if (fd_ < 0) throw Error(path_ + ": write after the file was closed");
  const char* p = static_cast<const char*>(data);
  while (size > 0) {
    const size_t take = std::min(size, kBufferBytes - buffer_.size());
    buffer_.insert(buffer_.end(), p, p + take);
    p += take;
    size -= take;
    if (buffer_.size() == kBufferBytes) flush();
  }
}

void AtomicFile::commit() {
  if (fd_ < 0) throw Error(path_ + ": commit after the file was closed");
  flush();
  if (::fsync(fd_) != 0 && errno != EINVAL) fail("flushing to disk (fsync)", errno);
  const int fd = fd_;
  fd_ = -1;
  if (::close(fd) != 0) {
    fd_ = -1;
    const int err = errno;
    ::unlink(temp_.c_str());
    throw Error(path_ + ": closing the written file failed: " + write_error_text(err) +
                "; the file was not changed");
  }
  // The temporary holds exactly what was written: a short file means lost data.
  struct stat st {};
  if (::stat(temp_.c_str(), &st) != 0 || uint64_t(st.st_size) != uint64_t(written_)) {
    ::unlink(temp_.c_str());
    throw Error(path_ + ": the written file has " + std::to_string(uint64_t(st.st_size)) +
                " bytes instead of " + std::to_string(written_) + "; the file was not changed");
  }
  if (::rename(temp_.c_str(), path_.c_str()) != 0) {
    const int err = errno;
    ::unlink(temp_.c_str());
    throw Error(path_ + ": cannot move the written file into place: " + write_error_text(err));
  }
  committed_ = true;
  // The rename is durable once the folder is synced; a failure here loses nothing written.
  fs::path dir = fs::path(path_).parent_path();
  if (dir.empty()) dir = ".";
  const int dfd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dfd >= 0) {
    ::fsync(dfd);
    ::close(dfd);
  }
}

void write_file_atomically(const std::string& path, std::string_view bytes) {
  AtomicFile f(path);
  f.write(bytes);
  f.commit();
}

void check_output_path(const std::string& path, const std::string& option,
                       const std::vector<std::string>& extensions,
                       const std::vector<std::string>& inputs) {
  const std::string name = option.empty() ? path : option + " " + path;
  if (path.empty()) throw ParamError(option + ": give a file name");
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (fs::is_directory(st))
    throw ParamError(
        name + ": is a directory; give a file name inside it, e.g. " +
        (fs::path(path) / ("out" + (extensions.empty() ? "" : extensions[0]))).string());
  if (fs::exists(st) && !fs::is_regular_file(st))
    throw ParamError(name +
                     ": exists and is not a regular file (a device, FIFO or socket); "
                     "kdgrid replaces outputs as a whole, give a regular file name");
  if (!extensions.empty()) {
    const std::string ext = lower_extension(path);
    if (std::find(extensions.begin(), extensions.end(), ext) == extensions.end()) {
      std::string list;
      for (const std::string& e : extensions) list += (list.empty() ? "" : ", ") + e;
      throw ParamError(name + ": the extension '" + ext + "' does not match what is written (" +
                       list + "); name the file with " +
                       (extensions.size() == 1 ? "that extension" : "one of these"));
    }
  }
  fs::path dir = fs::path(path).parent_path();
  if (dir.empty()) dir = ".";
  if (!fs::is_directory(dir, ec))
    throw ParamError(name + ": output folder '" + dir.string() +
                     "' does not exist; create it first (mkdir -p " + dir.string() + ")");
  if (::access(dir.c_str(), W_OK) != 0)
    throw ParamError(name + ": output folder '" + dir.string() + "' is not writable");
  const size_t name_bytes = fs::path(path).filename().string().size(),
               max_bytes = max_name_bytes(dir);
  if (name_bytes > max_bytes)
    throw ParamError(name + ": the file name is " + std::to_string(name_bytes) +
                     " bytes long and the file system of '" + dir.string() + "' takes at most " +
                     std::to_string(max_bytes) + "; choose a shorter name");
  if (path.size() >= size_t(PATH_MAX))
    throw ParamError(name + ": the path is " + std::to_string(path.size()) +
                     " bytes long, at most " + std::to_string(PATH_MAX - 1) +
                     " are allowed; write to a folder with a shorter path");
  // The very temporary the writer will create, created and removed: whatever would stop the
  // write at its start (a name the file system refuses, no free inode) stops it now.
  try {
    AtomicFile probe(path);
  } catch (const Error& e) {
    throw ParamError((option.empty() ? "" : option + " ") + e.what());
  }
  if (fs::exists(st))
    for (const std::string& in : inputs) {
      if (in.empty()) continue;
      std::error_code eq;
      if (fs::equivalent(path, in, eq))
        throw ParamError(name + ": is the same file as the input " + in +
                         "; writing it would destroy the input, choose another output name");
    }
}

}  // namespace kdgrid
