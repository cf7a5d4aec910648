// The build flags shared by the CLI and the viewer (src/cli/common.cpp): each is named after the
// BuildParams field it sets, sets that field, and its earlier name, if it had one, still works.
#include <gtest/gtest.h>

#include <fstream>
#include <functional>
#include <regex>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "cli/common.h"
#include "cli_util.h"
#include "test_util.h"

namespace kdgrid::test {
namespace {

using cli::AccelOptions;

/// One flag of AccelOptions: its name, its earlier name ("" if it never had another), the
/// value given after either ("" for a switch) and what that must do to the parsed options.
struct FlagCase {
  std::string name, earlier, value;
  std::function<bool(const AccelOptions&, const BuildParams&)> set;
};

const std::vector<FlagCase>& flag_cases() {
  static const std::vector<FlagCase> cases = {
      {"--accel", "", "kdtree",
       [](const AccelOptions& o, const BuildParams&) { return o.accel == "kdtree"; }},
      {"--cell-size", "", "0.25",
       [](const AccelOptions&, const BuildParams& p) { return p.cell_size == 0.25f; }},
      {"--cell-percentile", "", "50",
       [](const AccelOptions&, const BuildParams& p) { return p.cell_percentile == 50.0f; }},
      {"--hybrid-dense-matrix", "--dense-matrix", "",
       [](const AccelOptions&, const BuildParams& p) { return p.hybrid_dense_matrix; }},
      {"--triangle-test", "", "moller",
       [](const AccelOptions&, const BuildParams& p) {
         return p.triangle_test == TriangleTestKind::Moller;
       }},
      {"--grid-lambda", "", "2",
       [](const AccelOptions&, const BuildParams& p) { return p.grid_lambda == 2.0f; }},
      {"--kd-intersection-cost", "--kd-cost-ratio", "3",
       [](const AccelOptions&, const BuildParams& p) { return p.kd_intersection_cost == 3.0f; }},
      {"--hybrid-intersection-cost", "--hybrid-cost-ratio", "3.5",
       [](const AccelOptions&, const BuildParams& p) {
         return p.hybrid_intersection_cost == 3.5f;
       }},
      {"--hybrid-subtree-min", "--hybrid-subtree", "7",
       [](const AccelOptions&, const BuildParams& p) { return p.hybrid_subtree_min == 7u; }},
      {"--hybrid-max-build-seconds", "", "20",
       [](const AccelOptions&, const BuildParams& p) {
         return p.hybrid_max_build_seconds == 20.0;
       }},
      {"--hybrid-no-expand-empty", "--hybrid-no-expand", "",
       [](const AccelOptions&, const BuildParams& p) { return !p.hybrid_expand_empty; }},
      {"--hybrid-no-flat-subtrees", "", "",
       [](const AccelOptions&, const BuildParams& p) { return !p.hybrid_flat_subtrees; }},
      {"--hybrid-no-next-leaf-cache", "--hybrid-no-guess", "",
       [](const AccelOptions&, const BuildParams& p) { return !p.hybrid_next_leaf_cache; }},
      {"--bvh-max-leaf", "--bvh-leaf", "3",
       [](const AccelOptions&, const BuildParams& p) { return p.bvh_max_leaf == 3; }},
      {"--irregular-top-density", "--irr-top-density", "0.5",
       [](const AccelOptions&, const BuildParams& p) { return p.irregular_top_density == 0.5f; }},
      {"--irregular-sub-density", "--irr-sub-density", "1.5",
       [](const AccelOptions&, const BuildParams& p) { return p.irregular_sub_density == 1.5f; }},
      {"--embree-quality", "", "high",
       [](const AccelOptions&, const BuildParams& p) { return p.embree_quality == "high"; }},
      {"--embree-isa", "", "sse4.2",
       [](const AccelOptions&, const BuildParams& p) { return p.embree_isa == "sse4.2"; }},
      {"--memory-budget-mb", "", "64",
       [](const AccelOptions&, const BuildParams& p) {
         return p.memory_budget == (uint64_t(64) << 20);
       }},
      {"--brute-work-limit", "", "1e6",
       [](const AccelOptions&, const BuildParams& p) { return p.brute_work_limit == 1e6; }},
  };
  return cases;
}

/// AccelOptions parsed from `args` (shell words, no program name) and resolved.
struct Parsed {
  AccelOptions opts;
  BuildParams params;
};

Parsed parse(const std::string& args) {
  CLI::App app;
  Parsed r;
  r.opts.add_to(&app);
  app.parse(args, false);
  r.params = r.opts.resolve();
  return r;
}

/// The names of the data members of struct BuildParams, read from accel/params.h.
std::set<std::string> build_params_fields() {
  std::ifstream in(source_path("src/core/accel/params.h"));
  std::stringstream ss;
  ss << in.rdbuf();
  const std::string text = ss.str();
  const size_t begin = text.find("struct BuildParams {");
  const size_t end = text.find("\n};", begin);
  std::set<std::string> fields;
  if (begin == std::string::npos || end == std::string::npos) return fields;
  const std::string body = text.substr(begin, end - begin);
  // "  float kd_intersection_cost = 1.5f;", "  const CancelToken* cancel = nullptr;"
  const std::regex member(R"(\n  [A-Za-z_][\w:<>]*(?: \w+)*\*? (\w+) = )");
  for (std::sregex_iterator it(body.begin(), body.end(), member), e; it != e; ++it)
    fields.insert((*it)[1].str());
  return fields;
}

/// The field a build flag's name says it sets: dashes become underscores, the "no-" of a
/// switch that turns a knob off and the unit suffix "-mb" are dropped.
std::string field_named_by(std::string flag) {
  if (flag.rfind("--", 0) == 0) flag.erase(0, 2);
  if (const size_t no = flag.find("-no-"); no != std::string::npos) flag.erase(no, 3);
  if (flag.size() > 3 && flag.compare(flag.size() - 3, 3, "-mb") == 0) flag.resize(flag.size() - 3);
  for (char& c : flag)
    if (c == '-') c = '_';
  return flag;
}

TEST(CliFlags, EachBuildFlagIsNamedAfterTheFieldItSets) {
  const std::set<std::string> fields = build_params_fields();
  ASSERT_GT(fields.size(), 20u) << "could not read struct BuildParams from accel/params.h";
  ASSERT_TRUE(fields.count("hybrid_subtree_min")) << "the reader misses fields";
  CLI::App app;
  AccelOptions o;
  o.add_to(&app);
  int flags = 0;
  for (const CLI::Option* opt : app.get_options()) {
    if (opt->get_group() != "Acceleration structure") continue;
    ++flags;
    const std::string name = "--" + opt->get_lnames().at(0);
    if (name == "--accel") continue;  // chooses the structure; every other flag is one knob
    EXPECT_TRUE(fields.count(field_named_by(name)))
        << name << " names no BuildParams field (" << field_named_by(name)
        << "): name the flag after the field it sets, and keep the old name as its alias";
  }
  EXPECT_GT(flags, 15);
}

TEST(CliFlags, EachFlagSetsItsFieldAndItsEarlierNameStillDoes) {
  const Parsed defaults = parse("");
  for (const FlagCase& c : flag_cases()) {
    SCOPED_TRACE(c.name);
    // The check can fail: the defaults do not pass it.
    EXPECT_FALSE(c.set(defaults.opts, defaults.params));
    const std::string value = c.value.empty() ? "" : " " + c.value;
    const Parsed by_name = parse(c.name + value);
    EXPECT_TRUE(c.set(by_name.opts, by_name.params)) << c.name << value;
    if (c.earlier.empty()) continue;
    const Parsed by_earlier = parse(c.earlier + value);
    EXPECT_TRUE(c.set(by_earlier.opts, by_earlier.params)) << c.earlier << value;
  }
}

TEST(CliFlags, EveryBuildFlagIsCheckedAbove) {
  // flag_cases() covers every flag of AccelOptions, so a flag added later is tested too.
  std::set<std::string> covered;
  for (const FlagCase& c : flag_cases()) covered.insert(c.name);
  CLI::App app;
  AccelOptions o;
  o.add_to(&app);
  for (const CLI::Option* opt : app.get_options()) {
    if (opt->get_group() != "Acceleration structure") continue;
    const std::string name = "--" + opt->get_lnames().at(0);
    EXPECT_TRUE(covered.count(name)) << name << " has no case in flag_cases()";
  }
}

TEST(CliFlags, PrintedBuildFlagsUseTheFieldNamesAndRebuildTheSameParams) {
  // Every knob away from its default, as the viewer's pick prints it.
  BuildParams p;
  p.cell_size = 0.125f;
  p.cell_percentile = 75.0f;
  p.hybrid_dense_matrix = true;
  p.triangle_test = TriangleTestKind::Moller;
  p.grid_lambda = 2.5f;
  p.kd_intersection_cost = 0.1f;  // not exact in binary: it must read back the same
  p.hybrid_intersection_cost = 2.0f;
  p.hybrid_subtree_min = 9;
  p.hybrid_max_build_seconds = 30.0;
  p.hybrid_expand_empty = false;
  p.hybrid_next_leaf_cache = false;
  p.hybrid_flat_subtrees = false;
  p.bvh_max_leaf = 5;
  p.irregular_top_density = 0.3f;
  p.irregular_sub_density = 3.0f;
  p.embree_quality = "low";
  p.embree_isa = "sse4.2";
  p.memory_budget = uint64_t(512) << 20;
  p.brute_work_limit = 1e7;
  const std::string flags = cli::accel_flags("hybrid", p);
  for (const FlagCase& c : flag_cases()) {
    EXPECT_TRUE(contains(flags + " ", " " + c.name + " ")) << c.name << " not printed: " << flags;
    if (!c.earlier.empty()) {
      EXPECT_FALSE(contains(flags + " ", " " + c.earlier + " "))
          << c.earlier << " printed: " << flags;
    }
  }
  const Parsed back = parse(flags);
  const BuildParams& q = back.params;
  EXPECT_EQ(back.opts.accel, "hybrid");
  EXPECT_EQ(q.cell_size, p.cell_size);
  EXPECT_EQ(q.cell_percentile, p.cell_percentile);
  EXPECT_EQ(q.hybrid_dense_matrix, p.hybrid_dense_matrix);
  EXPECT_EQ(q.triangle_test, p.triangle_test);
  EXPECT_EQ(q.grid_lambda, p.grid_lambda);
  EXPECT_EQ(q.kd_intersection_cost, p.kd_intersection_cost);
  EXPECT_EQ(q.hybrid_intersection_cost, p.hybrid_intersection_cost);
  EXPECT_EQ(q.hybrid_subtree_min, p.hybrid_subtree_min);
  EXPECT_EQ(q.hybrid_max_build_seconds, p.hybrid_max_build_seconds);
  EXPECT_EQ(q.hybrid_expand_empty, p.hybrid_expand_empty);
  EXPECT_EQ(q.hybrid_next_leaf_cache, p.hybrid_next_leaf_cache);
  EXPECT_EQ(q.hybrid_flat_subtrees, p.hybrid_flat_subtrees);
  EXPECT_EQ(q.bvh_max_leaf, p.bvh_max_leaf);
  EXPECT_EQ(q.irregular_top_density, p.irregular_top_density);
  EXPECT_EQ(q.irregular_sub_density, p.irregular_sub_density);
  EXPECT_EQ(q.embree_quality, p.embree_quality);
  EXPECT_EQ(q.embree_isa, p.embree_isa);
  EXPECT_EQ(q.memory_budget, p.memory_budget);
  EXPECT_EQ(q.brute_work_limit, p.brute_work_limit);
  // The defaults print the structure alone.
  EXPECT_EQ(cli::accel_flags("bvh", BuildParams{}), " --accel bvh");
}

TEST(CliFlags, HelpListsEachFlagUnderTheFieldNameFirst) {
  const CliResult r = run_cli("trace --help");
  ASSERT_EQ(r.code, 0) << r.output;
  for (const FlagCase& c : flag_cases()) {
    const std::string listed = c.earlier.empty() ? c.name : c.name + "," + c.earlier;
    EXPECT_TRUE(contains(r.output, listed)) << listed << " not in:\n" << r.output;
  }
}

TEST(CliFlags, RefusalsNameTheFlagsByTheirFieldNames) {
  for (const auto& [args, named] : std::vector<std::pair<std::string, std::string>>{
           {"--kd-cost-ratio 0", "--kd-intersection-cost"},
           {"--bvh-leaf 0", "--bvh-max-leaf"},
           {"--irr-top-density 0", "--irregular-top-density"},
           {"--embree-isa avx3", "--embree-isa"}}) {
    try {
      parse(args);
      ADD_FAILURE() << args << " was accepted";
    } catch (const ParamError& e) {
      EXPECT_TRUE(contains(e.what(), named)) << args << ": " << e.what();
    }
  }
}

}  // namespace
}  // namespace kdgrid::test
