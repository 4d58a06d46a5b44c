// The core library must stay ROS-free (doc/design.md): no file under
// include/uw_multislam/core or src/core may include a ROS header; and the nodelets stay glue
// within a line budget. This test reads the sources.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <regex>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;

// Include prefixes that would tie the core to ROS.
const std::vector<std::string> kForbidden = {"ros/",
                                             "nodelet/",
                                             "pluginlib/",
                                             "image_transport/",
                                             "cv_bridge/",
                                             "tf2_ros/",
                                             "tf/",
                                             "rosbag/",
                                             "message_filters/",
                                             "diagnostic_updater/",
                                             "rostest/",
                                             "uw_multislam/ros/",
                                             "uw_multislam/msg",
                                             "uw_multislam/srv"};

// Returns the offending include lines of one file ("file:line: text").
std::vector<std::string> rosIncludes(const fs::path& file) {
  static const std::regex include_re(R"(^\s*#\s*include\s*[<"]([^>"]+)[>"])");
  static const std::regex msgs_re(R"(^[A-Za-z0-9_]+_(msgs|srvs)/)");
  std::vector<std::string> bad;
  std::ifstream in(file);
  std::string line;
  int n = 0;
  while (std::getline(in, line)) {
    ++n;
    std::smatch m;
    if (!std::regex_search(line, m, include_re)) continue;
    const std::string header = m[1];
    bool forbidden = std::regex_search(header, msgs_re);
    for (const auto& prefix : kForbidden) forbidden = forbidden || header.rfind(prefix, 0) == 0;
    if (forbidden) bad.push_back(file.string() + ":" + std::to_string(n) + ": " + line);
  }
  return bad;
}

std::vector<fs::path> sourcesUnder(const fs::path& dir) {
  std::vector<fs::path> files;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    const auto ext = e.path().extension();
    if (e.is_regular_file() && (ext == ".h" || ext == ".hpp" || ext == ".cpp" || ext == ".cc"))
      files.push_back(e.path());
  }
  return files;
}

TEST(CoreIsRosFree, DetectorFlagsRosIncludes) {
  // The detector itself must work, or the real check below would pass vacuously.
  const fs::path tmp = fs::temp_directory_path() / "uwms_ros_free_probe.h";
  {
    std::ofstream out(tmp);
    out << "#include <Eigen/Core>\n#include <ros/ros.h>\n  #  include \"sensor_msgs/Image.h\"\n#include <vector>\n";
  }
  const auto bad = rosIncludes(tmp);
  fs::remove(tmp);
  ASSERT_EQ(bad.size(), 2u);
  EXPECT_NE(bad[0].find("ros/ros.h"), std::string::npos);
  EXPECT_NE(bad[1].find("sensor_msgs/Image.h"), std::string::npos);
}

TEST(CoreIsRosFree, NoCoreFileIncludesRos) {
  const fs::path root(UWMS_SOURCE_DIR);
  std::vector<fs::path> files;
  for (const char* dir : {"include/uw_multislam/core", "src/core", "include/uw_multislam/sim", "src/sim"}) {
    ASSERT_TRUE(fs::is_directory(root / dir)) << (root / dir) << " is missing";
    const auto f = sourcesUnder(root / dir);
    files.insert(files.end(), f.begin(), f.end());
  }
  ASSERT_GE(files.size(), 6u) << "expected the core's headers and sources";
  std::vector<std::string> bad;
  for (const auto& f : files) {
    const auto b = rosIncludes(f);
    bad.insert(bad.end(), b.begin(), b.end());
  }
  std::string report;
  for (const auto& b : bad) report += "  " + b + "\n";
  EXPECT_TRUE(bad.empty()) << "ROS includes in the core library:\n" << report;
}

TEST(CoreIsRosFree, CoreDoesNotIncludeTheSimulator) {
  // The simulator is its own library (uw_multislam_sim) that the vehicle's code does not link:
  // a core file including a sim header would pull it back in.
  const fs::path root(UWMS_SOURCE_DIR);
  std::vector<std::string> bad;
  for (const char* dir : {"include/uw_multislam/core", "src/core"}) {
    for (const auto& f : sourcesUnder(root / dir)) {
      std::ifstream in(f);
      std::string line;
      while (std::getline(in, line))
        if (line.find("#include") != std::string::npos && line.find("uw_multislam/sim/") != std::string::npos)
          bad.push_back(f.string() + ": " + line);
    }
  }
  std::string report;
  for (const auto& b : bad) report += "  " + b + "\n";
  EXPECT_TRUE(bad.empty()) << "core files including the simulator:\n" << report;
}

// Nodelets only convert, call and publish (doc/design.md): logic that grows goes into the core, or
// into src/ros beside what it serves. A budget keeps that visible when a nodelet starts to grow.
TEST(ThinHeads, EachNodeletStaysWithinItsLineBudget) {
  constexpr int kBudget = 450;
  const auto nodelets = sourcesUnder(fs::path(UWMS_SOURCE_DIR) / "src" / "nodelets");
  ASSERT_GE(nodelets.size(), 3u) << "expected the odometry, loop detector and back-end nodelets";
  for (const auto& f : nodelets) {
    std::ifstream in(f);
    int lines = 0;
    for (std::string line; std::getline(in, line);) ++lines;
    EXPECT_LE(lines, kBudget) << f << ": move logic to the core or to src/ros";
  }
}

}  // namespace
