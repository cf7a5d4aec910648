// Enum name tables (util/enum_names.h): names out, values back, and the parse error's text.
#include <gtest/gtest.h>

#include <string>

#include "bench/raysets.h"
#include "render/renderer.h"
#include "scene/scene.h"
#include "util/enum_names.h"
#include "util/error.h"

namespace kdgrid {
namespace {

enum class Colour { Red, Green, Blue };
constexpr EnumName<Colour> kColourNames[] = {{Colour::Red, "red"}, {Colour::Green, "green"}};

TEST(EnumNames, NamesValuesAndWhatTheTableLacks) {
  EXPECT_STREQ(enum_name(Colour::Green, kColourNames), "green");
  EXPECT_STREQ(enum_name(Colour::Blue, kColourNames), "?");
  EXPECT_STREQ(enum_name(Colour::Blue, kColourNames, "red"), "red");
  EXPECT_EQ(enum_value("red", kColourNames), Colour::Red);
  EXPECT_FALSE(enum_value("blue", kColourNames).has_value());
  EXPECT_FALSE(enum_value("Red", kColourNames).has_value());
  EXPECT_EQ(parse_enum("green", kColourNames, "--colour", "choose red or green"), Colour::Green);
  try {
    parse_enum("blue", kColourNames, "--colour", "choose red or green");
    FAIL() << "accepted";
  } catch (const ParamError& e) {
    EXPECT_STREQ(e.what(), "--colour 'blue': choose red or green");
  }
}

TEST(EnumNames, EveryNameReadsBackAsItsValue) {
  for (const RaySetKind k :
       {RaySetKind::Primary, RaySetKind::Shadow, RaySetKind::Diffuse, RaySetKind::Random})
    EXPECT_EQ(parse_ray_set(to_string(k)), k) << to_string(k);
  for (const Shading s : {Shading::Lights, Shading::EyeLight, Shading::Normals})
    EXPECT_EQ(parse_shading(to_string(s), "--shading"), s) << to_string(s);
  for (const SecondaryOffset o :
       {SecondaryOffset::Robust, SecondaryOffset::Epsilon, SecondaryOffset::None})
    EXPECT_EQ(parse_secondary_offset(to_string(o), "--offset"), o) << to_string(o);
  for (const LightType t : {LightType::Point, LightType::Directional, LightType::Spot})
    EXPECT_EQ(enum_value(enum_name(t, kLightTypeNames), kLightTypeNames), t);
}

}  // namespace
}  // namespace kdgrid
