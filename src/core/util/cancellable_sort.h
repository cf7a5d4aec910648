// A parallel sort that polls a cancel token: the builders' first sort of every triangle's
// events (6 per triangle, 60 million for a 10-million-triangle scene) takes seconds, longer
// than a cancel may wait. The range is sorted in blocks in parallel, then merged pairwise in
// passes; the token is polled before each block and each merge, so a cancel waits for at most
// one block sort or one merge of two runs (the last merge is one sequential pass over all).
#pragma once

#include <algorithm>
#include <cstddef>
#include <iterator>

#include <tbb/parallel_for.h>

#include "util/cancel.h"

namespace kdgrid {

/// Elements per block sorted in one task: about 20 ms of std::sort for 12-byte events.
constexpr size_t kCancellableSortBlock = size_t(1) << 18;

/// Sorts [first, last) by `less` (a strict weak order; equal elements may end in any order,
/// as with std::sort) and throws BuildCancelled once `cancel` is set. Without a token it still
/// sorts in parallel.
template <class It, class Less>
void cancellable_sort(It first, It last, Less less, const CancelToken* cancel,
                      size_t block = kCancellableSortBlock) {
  const size_t n = size_t(std::distance(first, last));
  if (block == 0) block = 1;
  const size_t blocks = (n + block - 1) / block;
  check_cancel(cancel);
  if (blocks <= 1) {
    std::sort(first, last, less);
    return;
  }
  tbb::parallel_for(size_t(0), blocks, [&](size_t b) {
    check_cancel(cancel);
    const size_t lo = b * block, hi = std::min(n, lo + block);
    std::sort(first + std::ptrdiff_t(lo), first + std::ptrdiff_t(hi), less);
  });
  // Runs of `width` sorted elements are merged pairwise until one run is left.
  for (size_t width = block; width < n; width *= 2) {
    const size_t pairs = (n + 2 * width - 1) / (2 * width);
    tbb::parallel_for(size_t(0), pairs, [&](size_t p) {
      check_cancel(cancel);
      const size_t lo = p * 2 * width, mid = std::min(n, lo + width),
                   hi = std::min(n, lo + 2 * width);
      if (mid < hi)
        std::inplace_merge(first + std::ptrdiff_t(lo), first + std::ptrdiff_t(mid),
                           first + std::ptrdiff_t(hi), less);
    });
  }
  check_cancel(cancel);
}

}  // namespace kdgrid
