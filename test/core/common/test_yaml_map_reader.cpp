// Reading option structs from YAML (core/common/yaml_map_reader.h): a quoted scalar is text, so a
// number written in quotes is refused by key like any other text where a number is expected.
#include <gtest/gtest.h>

#include <cstdint>
#include <fstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "uw_multislam/core/common/yaml_map_reader.h"
#include "uw_multislam/core/session/slam_config.h"

namespace uw_multislam {
namespace core {
namespace {

// What reading `key` of the one-map document `yaml` as a T says: "" when it is read.
template <typename T>
std::string readRefusal(const std::string& yaml, const char* key, T* out) {
  try {
    MapReader r(parseYaml(yaml, "test"), "block");
    r.read(key, out);
    r.finish();
  } catch (const std::invalid_argument& e) {
    return e.what();
  }
  return "";
}

TEST(YamlMapReader, AQuotedNumberIsRefusedByKeyLikeOtherText) {
  int i = 0;
  double d = 0.0;
  bool b = false;
  std::uint64_t u = 0;
  std::vector<double> v;
  EXPECT_EQ(readRefusal("n: \"2\"", "n", &i),
            "block: bad value for 'n': \"2\" is quoted text, not a number (write it without quotes)");
  EXPECT_EQ(readRefusal("sigma: '0.5'", "sigma", &d),
            "block: bad value for 'sigma': \"0.5\" is quoted text, not a number (write it without quotes)");
  EXPECT_EQ(readRefusal("on: \"true\"", "on", &b),
            "block: bad value for 'on': \"true\" is quoted text, not a number (write it without quotes)");
  EXPECT_EQ(readRefusal("seed: \"20231122\"", "seed", &u),
            "block: bad value for 'seed': \"20231122\" is quoted text, not a number (write it without quotes)");
  EXPECT_EQ(readRefusal("xy: [1.0, \"2.0\"]", "xy", &v),
            "block: bad value for 'xy': \"2.0\" is quoted text, not a number (write it without quotes)");
  // Plain, they are read; other text is refused as before; a quoted string is a string.
  EXPECT_EQ(readRefusal("n: 2", "n", &i), "");
  EXPECT_EQ(i, 2);
  EXPECT_EQ(readRefusal("sigma: 0.5", "sigma", &d), "");
  EXPECT_EQ(d, 0.5);
  EXPECT_EQ(readRefusal("on: true", "on", &b), "");
  EXPECT_TRUE(b);
  EXPECT_EQ(readRefusal("xy: [1.0, 2.0]", "xy", &v), "");
  EXPECT_EQ(v, (std::vector<double>{1.0, 2.0}));
  EXPECT_EQ(readRefusal("n: two", "n", &i), "block: bad value for 'n'");
  std::string text;
  EXPECT_EQ(readRefusal("name: \"2\"", "name", &text), "");
  EXPECT_EQ(text, "2");
}

TEST(YamlMapReader, AQuotedNumberInTheSlamConfigurationIsRefusedNamingTheKey) {
  try {
    slamConfigFromYaml("odometry:\n  features:\n    num_features: \"2\"\n");
    FAIL() << "a quoted number was read";
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("odometry.features"), std::string::npos) << what;
    EXPECT_NE(what.find("'num_features': \"2\" is quoted text"), std::string::npos) << what;
  }
  // The shipped configuration files have no quoted number: they load.
  for (const char* file : {"/config/slam.yaml"}) {
    std::ifstream in(std::string(UWMS_SOURCE_DIR) + file);
    ASSERT_TRUE(in) << file;
    EXPECT_NO_THROW(loadSlamConfig(std::string(UWMS_SOURCE_DIR) + file)) << file;
  }
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
