"""Tests of scripts/walk_parts.py, the split of a ray query's code into parts that
scripts/ray-cost-split.sh and scripts/time-split.sh share: the innermost frame that names a
walk function decides, and the hybrid's own loop lines (read from walk.h) are leaf steps.
Run from anywhere: python3 scripts/test_walk_parts.py (ctest Scripts.WalkParts)."""
import os
import re
import sys
import unittest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "scripts"))
os.chdir(ROOT)  # walk_parts reads src/core/accel/hybrid/walk.h from the checkout
import walk_parts  # noqa: E402

TRAVERSE = ("bool kdgrid::GridKdHybrid::traverse<kdgrid::WatertightTest, kdgrid::NoProbe, false, "
            "false>(kdgrid::Ray const&, kdgrid::Hit*, kdgrid::NoProbe&) const")


def walk_h_line(pattern):
    src = open("src/core/accel/hybrid/walk.h").read().splitlines()
    start = next(i for i, l in enumerate(src) if re.search(r"Hybrid::traverse\(const Ray", l))
    return next(i for i in range(start, len(src)) if pattern in src[i]) + 1


class Parts(unittest.TestCase):
    def test_innermost_named_frame_decides(self):
        # A vec.h operator inlined into the triangle test is a test; into walk_begin, set-up.
        self.assertEqual(walk_parts.part([["kdgrid::operator-(Vec3, Vec3)", "vec.h:40"],
                                          ["kdgrid::WatertightTest::intersect(...)", "triangle.h:50"],
                                          [TRAVERSE, "walk.h:300"]]), "tests")
        self.assertEqual(walk_parts.part([["kdgrid::operator-(Vec3, Vec3)", "vec.h:40"],
                                          ["kdgrid::GridKdHybrid::walk_begin<...>(...)", "walk.h:350"],
                                          [TRAVERSE, "walk.h:300"]]), "setup")
        self.assertEqual(walk_parts.part([["kdgrid::kd_traverse<...>(...)", "kd_kernel.h:200"],
                                          ["kdgrid::GridKdHybrid::walk_step<...>(...)", "walk.h:600"]]),
                         "subtree")
        self.assertEqual(walk_parts.part([["kdgrid::GridKdHybrid::walk_flat<...>(...)", "walk.h:560"],
                                          ["kdgrid::GridKdHybrid::walk_step<...>(...)", "walk.h:640"]]),
                         "subtree")
        self.assertEqual(walk_parts.part([["kdgrid::GridKdHybrid::test_groups<...>(...)", "walk.h:480"],
                                          ["kdgrid::GridKdHybrid::walk_flat<...>(...)", "walk.h:590"]]),
                         "tests")
        self.assertEqual(walk_parts.part([["kdgrid::GridKdHybrid::next_leaf(...)", "walk.h:240"]]),
                         "steps")
        self.assertEqual(walk_parts.part([["kdgrid::hybrid::tested_before<false, ...>(...)", "walk.h:160"],
                                          ["kdgrid::GridKdHybrid::test_groups<...>(...)", "walk.h:480"]]),
                         "mailbox")
        self.assertEqual(walk_parts.part([["memcpy", "string.h:1"]]), "other")
        self.assertEqual(walk_parts.part([]), "other")

    def test_hybrid_loop_lines_are_steps_the_rest_setup(self):
        # Lines of traverse itself: its loop (from `for (;;)` to the call of walk_step) steps
        # over empty leaves; its entry and exit are the query's set-up.
        loop = walk_h_line("for (;;)") + 2
        entry = walk_h_line("for (;;)") - 3
        self.assertEqual(walk_parts.part([[TRAVERSE, f"walk.h:{loop}"]]), "steps")
        self.assertEqual(walk_parts.part([[TRAVERSE, f"walk.h:{entry}"]]), "setup")


if __name__ == "__main__":
    unittest.main()
