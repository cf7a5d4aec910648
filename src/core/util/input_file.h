// Checks made before any input file is opened: only regular files are read (a FIFO would
// block forever, /dev/zero or /dev/urandom would grow memory without end), and only up to a
// size limit, checked from the file's size before reading.
#pragma once

#include <cstdint>
#include <string>

namespace kdgrid {

/// Largest input file kdgrid reads into memory: the default memory budget
/// (default_memory_budget_bytes(), util/memory.h), since a file is held whole while it is
/// parsed.
uint64_t max_input_file_bytes();

/// Throws LoadError naming `path` (and `what`, e.g. "texture of material 'x'") unless it is
/// a regular file (symbolic links followed) of at most `max_bytes` bytes; returns its size.
uint64_t check_input_file(const std::string& path, const std::string& what = "",
                          uint64_t max_bytes = max_input_file_bytes());

/// check_input_file, then the whole file; LoadError when the read falls short.
std::string read_input_file(const std::string& path, const std::string& what = "",
                            uint64_t max_bytes = max_input_file_bytes());

}  // namespace kdgrid
