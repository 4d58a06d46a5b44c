// offline_slam: the SLAM core over dataset folders or bags, no ROS master. The main parses the command line
// into tools::OfflineOptions; tools::runOffline (offline_run.h) does the work, a bag read by
// ros_bag::BagStream (ros/bag_input.h). Contract: --help, doc/run_outputs.md, doc/tools/offline_slam.md.
#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cli.h"
#include "offline_run.h"
#include "uw_multislam/ros/bag_input.h"

namespace core = uw_multislam::core;
namespace po = boost::program_options;
namespace tools = uw_multislam::tools;

namespace {

const char* kUsage =
    R"(usage: offline_slam --session DIR [--session DIR ...] --out OUT [--config FILE] [--db FILE] [options]
       offline_slam --bag FILE [--bag FILE ...] --out OUT [topic and mount options] [options]

Runs uw_multislam over dataset folders (frames.csv, camera.yaml, images; see
doc/dataset_format.md), in the order given, as consecutive missions. Writes into OUT (columns in
doc/run_outputs.md): odometry.csv (odometry keyframe poses, each session in its own frame), trajectory.csv
(final keyframe poses in the frame of their map), loops.csv, loop_poses.csv (measured pose and covariance),
links.csv (joins), pieces.csv (the pieces tracking loss splits a folder into), nav_placements.csv (pieces and
sessions placed by the nav, --nav on), timing.csv, inputs.csv, config.yaml.
`session` is the folder's position on the command line, `index` the frame's index in frames.csv.
Sessions are joined into maps through one link (paper §9) once the global loops between them
support it (backend.join_policy: consistent, the default: a pairwise-consistent set of at least
backend.join_min_consistent loops with join_min_inliers inliers and join_min_spread_m spread; count:
backend.join_min_loops loops), and each map is optimised (backend.optimizer); `map` is the map's first session, whose frame it is.

With --db FILE (the session store, created if missing) the stored sessions keep their store ids,
the folders follow from the first id no session has had (the run prints which folder got which
session ids once); global loops are searched against them and everything is written to the
store as it happens. A folder already in it (frame indexes and stamps) is refused (exit status 3)
without --again. A run killed before it ended (kill -9, power cut) leaves the folder's session
`recording` in the store: running the folder again is refused (exit status 3) until you choose
with --interrupted:
  discard   delete the interrupted run's sessions (keyframes, motions, loops; the maps lose them)
            in one transaction, then process the folder again as usual;
  finish    keep what was stored, mark the session finished, and skip the folder in this run
            (when every folder is skipped, the run ends with status 0 and writes nothing to OUT).

A bag (--bag) is one stream, like a folder: its images (raw, or <image>/compressed), camera_info,
altitude (sensor_msgs/Range), nav (nav_msgs/Odometry) and the sensor mounts (/tf_static) are read
straight from it, as fast as the CPU allows; a frame's index is its image's position in the bag.
Bags and folders are not mixed in one run (run them one after the other with the same --db).

options:
  --session DIR     a dataset folder (repeat for several missions)
  --bag FILE[,FILE...]  a recorded bag, or one dive's bags (rosbag record --split) read as one
                    (repeat: consecutive missions, each its own stream)
  --ns NS           the namespace relative topic names resolve in (default /)
  --image-topic T, --camera-info-topic T, --altitude-topic T, --nav-topic T
                    default camera/image_raw, camera/camera_info, altitude, nav/odom
  --camera-info-url URL  the calibration file for a bag without camera_info
  --dvl-topic T [--dvl-field F] [--dvl-frame ID]  the altitude from a DVL's own message (any type): the
                    number at field path F (default altitude), frame ID (default header: its own)
  --camera-mount "X Y Z YAW"  the camera in the base frame (as the launch files' camera_mount),
                    instead of the bag's /tf_static; --altimeter-mount "X Y Z" (default: at the camera)
  --base-frame F    the vehicle's frame in /tf_static and the nav (default base_link)
  --out OUT         output directory (created)
  --config FILE     YAML configuration (see config/slam.yaml; --dump-config shows every key)
  --db FILE         the session store (SQLite) to read and extend
  --again           process folders already in the store once more (as new sessions)
  --detect-loops    first search global loops among the stored sessions (each against those
                    stored before it; loops already stored are skipped) and join what they
                    support (backend.join_policy), so stored sessions join without a new one;
                    --session may then be left out
  --add-link A:KA:B:KB[:X:Y:YAW:SXY:SYAW]
                    with --db (repeatable): the operator's link between keyframe KA of stored
                    session A and keyframe KB of stored session B (the back-end's add_link):
                    with the pose of KB in KA's frame (m, rad) and standard deviations, or
                    without it measured by RANSAC between the two stored keyframes ("find it").
                    Applied after --detect-loops, before the folders; a link is a loop like a
                    detector's (stored, counted towards joins). Every link is checked (and
                    measured) before any is added: one refused, none is, exit status 1.
  --interrupted discard|finish
                    what to do with a folder's run that was interrupted (above)
  --localise-only   with --db: the store is read, never written (localisation mode, as the
                    back-end's set_mode localisation): the folders are tracked and their loops to
                    the stored sessions found, automatic joins wait, OUT gets the outputs; the
                    store stays byte-identical. Not with --detect-loops or --interrupted
  --finish-after N  end each folder's session after its first N frames (as the back-end's
                    finish_session): the folder's later frames are dropped, counted and printed,
                    the session is finished (stored as finished with --db) and the next folder
                    starts the next session as usual
  --nav on|off      use a folder's nav.csv (dead reckoning) as a prior (default: nav.enabled, on)
  --threads N       worker threads that read, enhance and extract (SIFT) the next frames while
                    the main thread matches, detects loops and optimises (default 1: all in one
                    thread, one core); the outputs are the same for any N
  --dump-config     print the effective configuration and exit
  --quiet           no per-session summary
  -h, --help        this text

Exit status 0 on success, 2 on bad arguments, 1 with a one-line reason on bad input (a bag without
a topic or a mount it needs: the reason names it and the option that gives it), 3 when a
folder is already in the store (the one-line reason names the option to pass: --again, or
--interrupted discard|finish).)";

std::string parseNav(const std::string& text, std::optional<bool>* on) {
  if (text != "on" && text != "off") return "--nav takes on or off, not '%value%'";
  *on = text == "on";
  return "";
}

std::string parseInterrupted(const std::string& text, std::optional<core::InterruptedChoice>* choice) {
  if (text != "discard" && text != "finish") return "--interrupted takes discard or finish, not '%value%'";
  *choice = text == "discard" ? core::InterruptedChoice::kDiscard : core::InterruptedChoice::kFinish;
  return "";
}

std::string parseAddLink(const std::string& spec, tools::OperatorLink* link) {
  if (tools::parseOperatorLink(spec, link)) return "";
  return "bad --add-link '%value%': A:KA:B:KB (find it) or A:KA:B:KB:X:Y:YAW:SXY:SYAW (sigmas >= 1e-6)";
}

template <std::size_t N>
std::string parseMount(const std::string& text, std::optional<std::array<double, N>>* mount) {
  std::array<double, N> v;
  if (!uw_multislam::ros_bag::parseMount(text, N, v.data()))
    return "'%value%' is not " + std::to_string(N) + " numbers";
  *mount = v;
  return "";
}

// The command line into *o, every value and combination checked; std::nullopt, or the exit status to return.
std::optional<int> parseArguments(int argc, char** argv, tools::OfflineOptions* o,
                                  uw_multislam::ros_bag::BagInputOptions* b) {
  tools::CommandLine cli("offline_slam", kUsage);
  auto option = cli.add();
  option("session", po::value(&o->folders));
  option("bag", po::value(&o->bags));
  option("ns", po::value(&b->ns));
  option("image-topic", po::value(&b->image));
  option("camera-info-topic", po::value(&b->camera_info));
  option("altitude-topic", po::value(&b->altitude));
  option("nav-topic", po::value(&b->nav));
  option("camera-info-url", po::value(&b->camera_info_url));
  option("dvl-topic", po::value(&b->dvl_topic));
  option("dvl-field", po::value(&b->dvl_field));
  option("dvl-frame", po::value(&b->dvl_frame));
  option("camera-mount", tools::checked(&b->camera_mount, parseMount<4>));
  option("altimeter-mount", tools::checked(&b->altimeter_mount, parseMount<3>));
  option("base-frame", po::value(&b->base_frame));
  option("out", po::value(&o->out));
  option("config", po::value(&o->config_file));
  option("db", po::value(&o->db));
  option("again", tools::flag(&o->again));
  option("detect-loops", tools::flag(&o->detect_loops));
  option("add-link", tools::checkedEach(&o->links, parseAddLink));
  option("interrupted", tools::checked(&o->interrupted, parseInterrupted));
  option("localise-only", tools::flag(&o->localise_only));
  option("finish-after", tools::integer(&o->finish_after, 1, 100000000, "a number of frames, 1 or more"));
  option("nav", tools::checked(&o->nav, parseNav));
  option("threads", tools::integer(&o->threads, 1, 64));
  option("dump-config", tools::flag(&o->dump_config));
  option("quiet", tools::flag(&o->quiet));
  if (const auto status = cli.parse(argc, argv)) return status;
  const bool store = !o->db.empty();
  if (o->interrupted && !store) return cli.bad("--interrupted needs --db FILE");
  if (o->dump_config) return std::nullopt;  // nothing else is needed to print the configuration
  if (o->detect_loops && !store) return cli.bad("--detect-loops needs --db FILE");
  if (o->localise_only && !store) return cli.bad("--localise-only needs --db FILE");
  if (o->localise_only && (o->detect_loops || o->interrupted))
    return cli.bad("--localise-only writes nothing to the store: not with --detect-loops or --interrupted");
  if (!o->links.empty() && !store) return cli.bad("--add-link needs --db FILE");
  if (!o->links.empty() && o->localise_only)
    return cli.bad("--localise-only writes nothing to the store: not with --add-link");
  if (!o->folders.empty() && !o->bags.empty())
    return cli.bad("--session and --bag are not mixed in one run: run them one after the other with the same --db");
  if (b->altimeter_mount && !b->camera_mount) return cli.bad("--altimeter-mount needs --camera-mount");
  if (o->folders.empty() && o->bags.empty() && !o->detect_loops && o->links.empty())
    return cli.bad("at least one --session DIR or --bag FILE is required");
  if (o->out.empty()) return cli.bad("--out OUT is required");
  return std::nullopt;
}

}  // namespace

int main(int argc, char** argv) {
  tools::OfflineOptions options;
  uw_multislam::ros_bag::BagInputOptions bag;
  if (const auto status = parseArguments(argc, argv, &options, &bag)) return *status;
  options.open_bag = [&bag](const std::string& path, const core::SlamConfig& config) {
    bag.max_altitude_m = config.odometry.max_altitude_m;
    bag.read_nav = config.odometry.nav.enabled;
    auto s = std::make_shared<uw_multislam::ros_bag::BagStream>(path, bag);
    return tools::StreamInput{s->dataset(), [s](std::size_t i, std::string* why) { return s->image(i, why); },
                              s->recordedS(), s->summary()};
  };
  return tools::runOffline(options);
}
