#include "util/input_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>

#include "util/error.h"
#include "util/format.h"
#include "util/memory.h"

namespace kdgrid {

uint64_t max_input_file_bytes() {
  return default_memory_budget_bytes();
}

uint64_t check_input_file(const std::string& path, const std::string& what, uint64_t max_bytes) {
  const std::string name = what.empty() ? path : path + " (" + what + ")";
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0)
    throw LoadError(name + ": cannot read it (" + std::strerror(errno) + "); check the path");
  if (S_ISDIR(st.st_mode)) throw LoadError(name + ": is a directory; give a file");
  if (!S_ISREG(st.st_mode))
    throw LoadError(name +
                    ": is not a regular file (a FIFO, device or socket); kdgrid reads "
                    "regular files only, copy the data into a file first");
  if (uint64_t(st.st_size) > max_bytes)
    throw LoadError(name + ": " + format_bytes_iec(double(st.st_size)) +
                    " is larger than the input file limit of " +
                    format_bytes_iec(double(max_bytes)) +
                    " (the default memory budget: half of the memory available to kdgrid)");
  return uint64_t(st.st_size);
}

std::string read_input_file(const std::string& path, const std::string& what, uint64_t max_bytes) {
  const uint64_t size = check_input_file(path, what, max_bytes);
  const std::string name = what.empty() ? path : path + " (" + what + ")";
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) throw LoadError(name + ": cannot open it (" + std::strerror(errno) + ")");
  std::string data(size, '\0');
  size_t got = 0;
  while (got < size) {
    const ssize_t n = ::read(fd, data.data() + got, size - got);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = n < 0 ? errno : 0;
      ::close(fd);
      throw LoadError(name + ": read failed after " + std::to_string(got) + " of " +
                      std::to_string(size) + " bytes" +
                      (err ? std::string(" (") + std::strerror(err) + ")" : std::string()));
    }
    got += size_t(n);
  }
  ::close(fd);
  return data;
}

}  // namespace kdgrid
