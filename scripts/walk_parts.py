"""The parts of a ray query that scripts/ray-cost-split.sh (callgrind's instructions) and
scripts/time-split.sh (perf's time samples) split a ray's cost into, by the code an instruction
comes from:

  setup    the ray's validation, the clip to the structure's box (kd_begin) and, in the hybrid,
           the rest of walk_begin: the grid-space ray, the entry cell and its leaf (start_leaf)
  steps    the hybrid's leaf steps: traverse's loop and walk_step less their tests, leaf_exit,
           the next-leaf lookup (next_leaf, the cell map) and the step bound
  subtree  kd_traverse and kd_clip_x4 (kd_kernel.h): the kd-tree's whole traversal, the hybrid's
           walks of leaf subtrees; and the hybrid's walk_flat, its flat subtrees' walk
  tests    the triangle test (WatertightTest::intersect, the wide leaves' WatertightWide) and the
           loop over a leaf's groups (test_groups; the kd-tree's leaf loop)
  mailbox  the hybrid's per-ray mailbox (tested_before) and the exact walk's set
  other    anything else (calls into the C++ runtime; the exact walk's rewalk bookkeeping)

An instruction is assigned by its inline chain (addr2line -i over a build with line info): the
innermost frame that names one of the functions above decides, so a vec.h operator inlined into
the triangle test counts as a test, the same one inlined into walk_begin as set-up.
"""
import re
import subprocess

PARTS = ("setup", "steps", "subtree", "tests", "mailbox", "other")

_RULES = [("tests", ("Test::intersect", "WatertightWide<")),
          ("mailbox", ("tested_before", "TestedSet")), ("tests", ("test_groups",)),
          ("subtree", ("kd_traverse", "kd_clip_x4", "walk_flat")),
          ("setup", ("walk_begin", "kd_begin", "start_leaf")),
          ("steps", ("leaf_exit", "exit_through", "next_leaf", "walk_step", "over_step_bound")),
          ("other", ("rewalk",)),
          ("setup", ("AcceleratorBase",))]


def inline_chains(binary, addresses):
    """{address: [[function, file:line], ...]} (innermost frame first) for static addresses of
    `binary`, from addr2line -i."""
    chains = {}
    if not addresses:
        return chains
    out = subprocess.run(["addr2line", "-a", "-i", "-f", "-C", "-e", binary] +
                         [hex(a) for a in addresses], capture_output=True, text=True).stdout
    cur, odd = None, False
    for line in out.splitlines():
        if re.fullmatch(r"0x[0-9a-f]+", line):
            cur, odd = int(line, 16), False
            chains[cur] = []
        elif cur is not None:
            if not odd:
                chains[cur].append([line, ""])  # a frame's function, then its file:line
            else:
                chains[cur][-1][1] = line
            odd = not odd
    return chains


def _hybrid_loop_lines(walk_h="src/core/accel/hybrid/walk.h"):
    # The hybrid's walk itself: its loop (the empty leaves it steps over inline, the call of
    # walk_step) is steps, the rest (entry, exit, the answer's copy) set-up. Its loop's lines
    # are read from walk.h: from `for (;;)` to the call of walk_step.
    src = open(walk_h).read().splitlines()
    w0 = next(i for i, l in enumerate(src) if re.search(r"Hybrid::traverse\(const Ray", l))
    return (next(i for i in range(w0, len(src)) if "for (;;)" in src[i]) + 1,
            next(i for i in range(w0, len(src)) if "walk_step<" in src[i]) + 1)


_LOOP = None


def part(chain):
    """The part (PARTS) of an instruction with inline chain `chain` (inline_chains)."""
    global _LOOP
    for f, loc in chain:
        if re.search(r"Hybrid::traverse<", f):
            if _LOOP is None:
                _LOOP = _hybrid_loop_lines()
            m = re.search(r"walk\.h:(\d+)", loc)
            return "steps" if m and _LOOP[0] <= int(m.group(1)) <= _LOOP[1] else "setup"
        for k, names in _RULES:
            if any(n in f for n in names):
                return k
        # The kd-tree's leaf loop is a lambda inside its query: a frame whose name is a lambda
        # in kdtree's code is a test loop.
        if "KdTree" in f and "lambda" in f:
            return "tests"
    return "other"
