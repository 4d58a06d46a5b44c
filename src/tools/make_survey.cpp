// make_survey: renders bottom-looking camera missions over a seabed world with exact ground
// truth. See --help, and README.md "Survey generator".
#include <algorithm>
#include <cctype>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>  // isatty

#include "cli.h"

#include "uw_multislam/ros/dataset_bag.h"
#include "uw_multislam/sim/survey_config.h"

namespace core = uw_multislam::core;
namespace ros_bag = uw_multislam::ros_bag;
namespace fs = std::filesystem;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage = R"(usage: make_survey --out DIR [--preset NAME | --config FILE] [options]

Renders camera missions over a seabed with exact ground truth. Writes into DIR:
  <session>/          one dataset folder per session: NNNN.jpg, frames.csv, camera.yaml, gt.csv;
                      with the session's nav enabled nav.csv, in gt.csv's frame or (nav.frame
                      enu/ned) in the survey's world frame with nav_frame.yaml (doc/dataset_format.md)
  <session>.bag       the same session as a ROS bag (/camera/image_raw, /camera/camera_info,
                      /altitude as sensor_msgs/Range, /ground_truth/odom as nav_msgs/Odometry)
  world_gt.csv        session,index,x_m,y_m,yaw_rad: every frame in one world frame
  loops_gt.csv        session_a,index_a,session_b,index_b: the revisits a loop detector should
                      find (centres closer than 40 % of the footprint height, not neighbours)
  survey.yaml         the full effective spec: rerun it with --config DIR/survey.yaml

options:
  --out DIR           output directory (created; its session folders are replaced)
  --preset NAME       a built-in survey (default: demo); --list-presets shows them
  --config FILE       a YAML survey spec (may start from a preset with "preset: NAME");
                      --dump-config shows every key with its value
  --seed N            seed of the world and of all noise (default: the spec's, 1)
  --mosaic IMAGE TXT  fly over a georeferenced mosaic instead of the procedural seabed, e.g.
                      ../shared/data/acfr/test4/mosaic.jpg ../shared/data/acfr/test4/mosaic.txt
                      (the missions must then fit inside the imaged area)
  --distortion K1,K2  radial lens distortion of every session's camera (plumb_bob k1, k2; up to
                      five numbers k1,k2,p1,p2,k3): the images are rendered through that lens and
                      camera.yaml / camera_info carry D (a camera's "distortion" key does the same)
  --no-bag            write the dataset folders only
  --dump-config       print the effective spec as YAML and exit
  --list-presets      print the preset names and exit
  --quiet             no progress output
  -h, --help          this text

Exit status 0 on success, 2 on bad arguments, 1 with a one-line reason on any other error.)";

struct Args {
  std::string out, preset = "demo", config, mosaic_image, mosaic_georef;
  std::vector<double> distortion;
  bool no_bag = false, dump = false, list = false, quiet = false;
  std::optional<unsigned long long> seed;  // unset: the spec's
};

// "bad seed '...'" unless the text is an unsigned 64-bit integer, digits only: strtoull skips leading space,
// takes a sign (" -1" wraps to 2^64 - 1) and clamps past 2^64 - 1, each making two seeds one survey.
std::string parseSeed(const std::string& text, std::optional<unsigned long long>* seed) {
  const char* v = text.c_str();
  char* end = nullptr;
  errno = 0;
  const unsigned long long n = std::strtoull(v, &end, 10);
  if (!std::isdigit(static_cast<unsigned char>(*v)) || *end != '\0' || errno == ERANGE)
    return "bad seed '%value%': an integer in [0, 18446744073709551615]";
  *seed = n;
  return "";
}

// --distortion k1[,k2[,p1,p2,k3]]: 1 to 5 finite numbers.
std::string parseDistortion(const std::string& text, std::vector<double>* distortion) {
  std::stringstream ss(text);
  std::string cell;
  distortion->clear();
  while (std::getline(ss, cell, ',')) {
    double d = 0.0;
    if (!tools::parseNumber(cell, &d)) return "--distortion: bad number '" + cell + "'";
    distortion->push_back(d);
  }
  if (distortion->empty() || distortion->size() > 5) return "--distortion needs 1 to 5 numbers";
  return "";
}

std::optional<int> parseArguments(int argc, char** argv, Args* a) {
  std::vector<std::string> mosaic;  // IMAGE TXT
  tools::CommandLine cli("make_survey", kUsage);
  auto option = cli.add();
  option("out", po::value(&a->out));
  option("preset", po::value(&a->preset));
  option("config", po::value(&a->config));
  option("seed", tools::checked(&a->seed, parseSeed));
  option("mosaic", po::value(&mosaic)->multitoken());
  option("distortion", tools::checked(&a->distortion, parseDistortion));
  option("no-bag", tools::flag(&a->no_bag));
  option("dump-config", tools::flag(&a->dump));
  option("list-presets", tools::flag(&a->list));
  option("quiet", tools::flag(&a->quiet));
  if (const auto status = cli.parse(argc, argv)) return status;
  if (!mosaic.empty() && mosaic.size() != 2) return cli.bad("--mosaic needs an image and its georeference text file");
  if (mosaic.size() == 2) a->mosaic_image = mosaic[0], a->mosaic_georef = mosaic[1];
  if (a->list) return std::nullopt;
  if (cli.given("preset") && !a->config.empty()) return cli.bad("give --preset or --config, not both");
  if (!a->dump && a->out.empty()) return cli.bad("--out DIR is required");
  return std::nullopt;
}

int makeSurvey(const Args& a) {
  if (a.list) {
    for (const auto& p : core::surveyPresets()) std::puts(p.c_str());
    return 0;
  }
  try {
    core::SurveySpec spec = a.config.empty() ? core::surveyPreset(a.preset) : core::loadSurveyYaml(a.config);
    if (a.seed) spec.seed = *a.seed;
    for (auto& s : spec.sessions) {
      if (a.distortion.empty()) break;
      s.camera.distortion_model = core::DistortionModel::kPlumbBob;
      s.camera.distortion = a.distortion;
      s.camera.distortion.resize(5, 0.0);
    }
    if (!a.mosaic_image.empty()) {
      spec.world.mosaic_image = a.mosaic_image;
      spec.world.mosaic_georef = a.mosaic_georef;
    }
    if (a.dump) {
      std::fputs(core::surveyToYaml(spec).c_str(), stdout);
      return 0;
    }

    const auto t0 = std::chrono::steady_clock::now();
    int last_session = -1;
    // On a terminal one line per session, rewritten in place; in a log (not a terminal) a line at
    // every 10 % and at the end of each session, so that logs stay readable.
    const bool terminal = isatty(fileno(stderr)) != 0;
    const auto progress = [&](int session, int frame, int total) {
      if (a.quiet) return;
      const char* name = spec.sessions[session].name.c_str();
      if (!terminal) {
        const int step = std::max(1, (total + 9) / 10);  // at most 10 lines and the last
        if ((frame + 1) % step == 0 || frame + 1 == total) {
          std::fprintf(stderr, "rendering %s: %d/%d\n", name, frame + 1, total);
        }
        return;
      }
      if (session != last_session) {
        if (last_session >= 0) std::fprintf(stderr, "\n");
        last_session = session;
      }
      std::fprintf(stderr, "\rrendering %s: %d/%d", name, frame + 1, total);
    };
    const core::SurveyResult r = core::generateSurvey(spec, a.out, progress);
    if (!a.quiet && terminal && last_session >= 0) std::fprintf(stderr, "\n");
    {
      std::ofstream yaml(fs::path(a.out) / "survey.yaml");
      yaml << "# Effective survey spec written by make_survey; rerun with --config this file.\n"
           << core::surveyToYaml(spec);
    }
    std::size_t bag_bytes = 0;
    if (!a.no_bag) {
      for (const auto& dir : r.session_dirs) {
        const std::string bag = dir + ".bag";
        const auto stats = ros_bag::writeDatasetBag(core::loadDataset(dir), ros_bag::DatasetBagOptions(), bag);
        bag_bytes += stats.bag_bytes;
      }
    }
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    int inter = 0;
    for (const auto& l : r.loops) inter += l.session_a != l.session_b;
    std::printf(
        "make_survey: %zu sessions, %d frames (%d blank/occluded), %zu ground-truth loops (%d inter-session), "
        "world %.4f m/px, %s%.1f s -> %s\n",
        r.session_dirs.size(), r.frames, r.blank_frames, r.loops.size(), inter, r.metres_per_px,
        a.no_bag
            ? ""
            : (std::to_string(r.session_dirs.size()) + " bags " + std::to_string(bag_bytes / (1024 * 1024)) + " MiB, ")
                  .c_str(),
        secs, a.out.c_str());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "make_survey: %s\n", e.what());
    return 1;
  }
}

}  // namespace

int main(int argc, char** argv) {
  Args a;
  if (const auto status = parseArguments(argc, argv, &a)) return *status;
  return makeSurvey(a);
}
