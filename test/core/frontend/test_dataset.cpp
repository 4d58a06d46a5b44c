// Dataset folders: round trips and clear errors on broken files.
#include <gtest/gtest.h>
#include <sys/stat.h>

#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>

#include "../../common/scoped_temp_dir.h"
#include "uw_multislam/core/frontend/dataset.h"
#include "uw_multislam/core/frontend/image_file.h"
#include "uw_multislam/core/geometry/vehicle_frame.h"
#include "uw_multislam/core/session/slam_config.h"

namespace uw_multislam {
namespace core {
namespace {

namespace fs = std::filesystem;

class DatasetTest : public ::testing::Test {
 protected:
  void write(const std::string& name, const std::string& text) { std::ofstream(dir_ / name) << text; }
  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  // Expects loadDataset to throw a DatasetError whose message contains `needle`.
  void expectError(const std::string& needle) {
    try {
      loadDataset(dir_.string(), true, StampOrder::kRequired);  // as a SLAM run reads a folder
      FAIL() << "no error, expected one containing '" << needle << "'";
    } catch (const DatasetError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  }
  void writeValid() {
    CameraIntrinsics c{320, 240, 300.0, 301.0, 160.0, 120.0};
    writeCameraYaml(path("camera.yaml"), c);
    writeFramesCsv(path("frames.csv"), {{0, "0000.jpg", 0.0, 2.5}, {1, "0001.jpg", 0.5, 2.6}});
    write("0000.jpg", "x");
    write("0001.jpg", "x");
  }
  testing_util::ScopedTempDir tmp_{"uwms_dataset"};
  const fs::path dir_ = tmp_.path();
};

TEST_F(DatasetTest, RoundTrip) {
  writeValid();
  writeGroundTruthCsv(path("gt.csv"), {{0, "0000.jpg", Pose2(0, 0, 0)}, {1, "0001.jpg", Pose2(0.25, -0.5, 3.1)}});
  const Dataset d = loadDataset(dir_.string());
  EXPECT_EQ(d.camera.width, 320);
  EXPECT_DOUBLE_EQ(d.camera.fy, 301.0);
  ASSERT_EQ(d.frames.size(), 2u);
  EXPECT_EQ(d.frames[1].image, "0001.jpg");
  EXPECT_DOUBLE_EQ(d.frames[1].altitude_m, 2.6);
  EXPECT_DOUBLE_EQ(d.frames[1].stamp_s, 0.5);
  ASSERT_EQ(d.ground_truth.size(), 2u);
  EXPECT_TRUE(approxEqual(d.ground_truth[1].pose, Pose2(0.25, -0.5, 3.1), 1e-6, 1e-6));
  EXPECT_EQ(d.imagePath(d.frames[0]), (dir_ / "0000.jpg").string());
}

TEST_F(DatasetTest, GroundTruthIsOptional) {
  writeValid();
  EXPECT_TRUE(loadDataset(dir_.string()).ground_truth.empty());
}

TEST_F(DatasetTest, ReadsTheSharedFormatWithSpaces) {
  write("camera.yaml",
        "# a comment\nimage_width: 680\nimage_height: 512\nfx: 1000.0\nfy: 1000.0\ncx: 340.0\ncy: 256.0\n");
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,0.000,2.3700\n\n1, 0001.jpg ,1.000,2.3108\n");
  write("0000.jpg", "x");
  write("0001.jpg", "x");
  const Dataset d = loadDataset(dir_.string());
  EXPECT_EQ(d.frames.size(), 2u);
  EXPECT_EQ(d.frames[1].image, "0001.jpg");
}

TEST_F(DatasetTest, ATextFileThatIsADirectoryIsRefusedNotReadAsEmpty) {
  try {
    readTextFile(dir_.string());
    FAIL() << "a directory read as a text file";
  } catch (const DatasetError& e) {
    EXPECT_NE(std::string(e.what()).find("a directory, not a file"), std::string::npos) << e.what();
  }
  EXPECT_THROW(loadSlamConfig(dir_.string()), std::exception);  // offline_slam --config DIR
  write("empty.yaml", "");
  EXPECT_EQ(readTextFile((dir_ / "empty.yaml").string()), "");  // an empty file is still read as one
}

TEST_F(DatasetTest, ImageFilesAreReadAsTheLiveOdometryReadsItsMessages) {
  cv::Mat grey(48, 64, CV_8UC1);
  cv::randu(grey, 0, 256);
  std::vector<std::uint8_t> jpeg;
  ASSERT_TRUE(cv::imencode(".jpg", grey, jpeg));
  const auto file = [&](const std::string& name, const std::vector<std::uint8_t>& bytes) {
    const std::string path = (dir_ / name).string();
    std::ofstream(path, std::ios::binary)
        .write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
    return path;
  };
  std::string why;
  cv::Mat got = readFrameImage(file("ok.jpg", jpeg), &why);
  ASSERT_EQ(got.type(), CV_8UC1) << why;
  EXPECT_EQ(got.size(), grey.size());
  // Cut off (a transfer that stopped): libjpeg would decode it with grey rows; refused, naming the file.
  const std::vector<std::uint8_t> cut(jpeg.begin(), jpeg.begin() + static_cast<long>(jpeg.size() / 2));
  const std::string cut_path = file("cut.jpg", cut);
  ASSERT_FALSE(cv::imread(cut_path, cv::IMREAD_COLOR).empty());  // what cv::imread alone did
  EXPECT_TRUE(readFrameImage(cut_path, &why).empty());
  EXPECT_NE(why.find(cut_path + ": corrupt image (truncated JPEG"), std::string::npos) << why;
  // Padding after the end-of-image marker is still a whole JPEG.
  std::vector<std::uint8_t> padded = jpeg;
  padded.insert(padded.end(), {0, 0, '\n'});
  EXPECT_FALSE(readFrameImage(file("padded.jpg", padded), &why).empty()) << why;
  // 12-bit data in a 16-bit PNG: scaled by its range (4095 -> 255), not by 65535 (-> 0..15).
  cv::Mat twelve(48, 64, CV_16UC1);
  cv::randu(twelve, 0, 4096);
  twelve.at<std::uint16_t>(0, 0) = 4095;
  std::vector<std::uint8_t> png;
  ASSERT_TRUE(cv::imencode(".png", twelve, png));
  got = readFrameImage(file("twelve.png", png), &why);
  ASSERT_EQ(got.type(), CV_8UC1) << why;
  double lo = 0, hi = 0;
  cv::minMaxLoc(got, &lo, &hi);
  EXPECT_EQ(hi, 255.0);
  EXPECT_EQ(got.at<std::uint8_t>(0, 1),
            cv::saturate_cast<std::uint8_t>(twelve.at<std::uint16_t>(0, 1) * 255.0 / 4095.0));
  // BGRA: alpha dropped; not an image, an empty file, a missing one: refused with the reason.
  cv::Mat bgra(8, 8, CV_8UC4, cv::Scalar(1, 2, 3, 4));
  ASSERT_TRUE(cv::imencode(".png", bgra, png));
  got = readFrameImage(file("bgra.png", png), &why);
  ASSERT_EQ(got.type(), CV_8UC3) << why;
  EXPECT_EQ(got.at<cv::Vec3b>(2, 2), cv::Vec3b(1, 2, 3));
  EXPECT_TRUE(readFrameImage(file("text.jpg", {'n', 'o', 't'}), &why).empty());
  EXPECT_NE(why.find("cannot decode image"), std::string::npos) << why;
  EXPECT_TRUE(readFrameImage(file("empty.png", {}), &why).empty());
  EXPECT_NE(why.find("empty file"), std::string::npos) << why;
  EXPECT_TRUE(readFrameImage((dir_ / "missing.png").string(), &why).empty());
  EXPECT_NE(why.find("cannot open"), std::string::npos) << why;
}

TEST_F(DatasetTest, ClearErrors) {
  expectError("camera.yaml: cannot open");
  writeValid();
  write("frames.csv", "index,image,stamp\n");
  expectError("unexpected header");
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,0.0,abc\n");
  expectError("frames.csv:2: bad number in altitude_m");
  // Saved by a spreadsheet as "CSV UTF-8": the byte-order mark is not part of the header.
  write("frames.csv", "\xEF\xBB\xBFindex,image,stamp_s,altitude_m\n0,0000.jpg,0.0,2.5\n1,0001.jpg,0.5,2.6\n");
  EXPECT_EQ(readFramesCsv((dir_ / "frames.csv").string(), StampOrder::kRequired).size(), 2u);
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,0.0,0x10\n");  // strtod: 16
  expectError("frames.csv:2: bad number in altitude_m: '0x10'");
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,0.0,2\n0,0001.jpg,0.5,2\n");
  expectError("duplicate index 0");
  // Stamps out of order, repeated, or jumping by more than an hour (two missions in one folder):
  // refused for a SLAM run (kRequired), read as written otherwise (folder_to_bag writes them, counted).
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,10.0,2\n1,0001.jpg,5.0,2\n");
  expectError("frames.csv:3: stamp_s 5.0 is not after the previous frame's");
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,10.0,2\n1,0001.jpg,10.0,2\n");
  expectError("frames.csv:3: stamp_s 10.0 is not after");
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,10.0,2\n1,0001.jpg,86410.0,2\n");
  expectError("frames.csv:3: stamp_s jumps by 86400 s (more than 3600 s): two missions in one folder?");
  EXPECT_EQ(loadDataset(dir_.string()).frames.size(), 2u);  // read as written (folder_to_bag)
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,10.0,2\n1,0001.jpg,3610.0,2\n");
  EXPECT_EQ(readFramesCsv((dir_ / "frames.csv").string(), StampOrder::kRequired).size(), 2u);  // an hour: one mission
  // A frame without a time: refused for a SLAM run, wherever it sits (before: a nan stamp skipped the
  // order checks and failed only when its keyframe was stored, leaving a session cut short).
  for (const char* bad : {"nan", "inf", "-nan"}) {
    write("frames.csv", std::string("index,image,stamp_s,altitude_m\n0,0000.jpg,10.0,2\n1,0001.jpg,") + bad + ",2\n");
    expectError(std::string("frames.csv:3: stamp_s is not finite: '") + bad + "'");
    write("frames.csv", std::string("index,image,stamp_s,altitude_m\n0,0000.jpg,") + bad + ",2\n1,0001.jpg,10.0,2\n");
    expectError(std::string("frames.csv:2: stamp_s is not finite: '") + bad + "'");
  }
  EXPECT_EQ(loadDataset(dir_.string()).frames.size(), 2u);  // read as written (folder_to_bag refuses it itself)
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,0.0,2\n1,missing.jpg,0.5,2\n");
  expectError("image 'missing.jpg' of frame 1 does not exist");
  write("frames.csv", "index,image,stamp_s,altitude_m\n");
  expectError("no frames");
  write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,0.0\n");
  expectError("expected 4 columns, found 3");
  writeValid();
  write("camera.yaml", "image_width: 320\nimage_height: 240\nfx: 0\nfy: 300\ncx: 160\ncy: 120\n");
  expectError("focal length");
  write("camera.yaml", "\xEF\xBB\xBFimage_width: 320\nimage_height: 240\nfx: 300\nfy: 300\ncx: 160\ncy: 120\n");
  EXPECT_EQ(readCameraYaml(path("camera.yaml")).width, 320);  // a byte-order mark is not part of the key
  write("camera.yaml", "image_width: 320\nimage_height: 240\nfx: 1e-300\nfy: 300\ncx: 160\ncy: 120\n");
  expectError("is below one pixel");
  write("camera.yaml", "image_width: 320\nimage_height: 240\nfx: 300\nfy: 300\ncx: 5000\ncy: 120\n");
  expectError("principal point cx=5000 cy=120 is outside the 320x240 image");
  write("camera.yaml", "image_width: 320\nimage_height: 240\nfx: 300\nfy: 300\ncx: 160\n");
  expectError("missing key 'cy'");
}

// frames.csv names files inside its folder: an entry that leaves it (an absolute path, "..", a link
// out of the folder) is refused naming the line or the frame, even when what it names is a real image.
TEST_F(DatasetTest, ImageEntriesThatLeaveTheFolderAreRefused) {
  testing_util::ScopedTempDir outside_dir{"uwms_outside"};
  const fs::path outside = outside_dir.path() / "real.png";
  cv::Mat grey(48, 64, CV_8UC1, cv::Scalar(90));
  ASSERT_TRUE(cv::imwrite(outside.string(), grey));
  writeValid();
  const auto frames = [&](const std::string& second) {
    write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,0.0,2\n1," + second + ",0.5,2\n");
  };
  frames("../../etc/passwd");
  expectError("frames.csv:3: image '../../etc/passwd' climbs above the folder ('..')");
  frames("sub/../../x.jpg");
  expectError("frames.csv:3: image 'sub/../../x.jpg' climbs above the folder");
  frames("/etc/passwd");
  expectError("frames.csv:3: image '/etc/passwd' is an absolute path");
  frames(outside.string());  // a real image, absolute
  expectError("is an absolute path: an image entry is a file inside the folder");
  // Links: resolved, and compared with the folder's real path.
  fs::create_symlink(outside, dir_ / "link_out.png");
  frames("link_out.png");
  expectError("image 'link_out.png' of frame 1 resolves to " + fs::canonical(outside).string() +
              ", outside the folder");
  fs::create_directory(dir_ / "sub");
  fs::create_directory_symlink(outside_dir.path(), dir_ / "sub" / "elsewhere");
  frames("sub/elsewhere/real.png");
  expectError("image 'sub/elsewhere/real.png' of frame 1 resolves to");
  fs::create_symlink("/etc/passwd", dir_ / "passwd");
  frames("passwd");
  expectError("outside the folder");
  // Inside the folder, through links or subfolders, entries stay valid (and the folder itself may be
  // reached through a link).
  ASSERT_TRUE(cv::imwrite((dir_ / "sub" / "inner.png").string(), grey));
  fs::create_symlink("sub/inner.png", dir_ / "link_in.png");
  for (const char* ok : {"link_in.png", "sub/inner.png", "sub/../0001.jpg", "./0001.jpg"}) {
    frames(ok);
    EXPECT_EQ(loadDataset(dir_.string(), true, StampOrder::kRequired).frames[1].image, ok);
  }
  fs::create_directory_symlink(dir_, outside_dir.path() / "folder_link");
  frames("link_in.png");
  EXPECT_EQ(loadDataset((outside_dir.path() / "folder_link").string()).frames.size(), 2u);
}

// An entry that is a directory or a FIFO says what it is, and the FIFO is never opened (a reader
// would block until a writer came): loading, and reading it as an image, return at once.
TEST_F(DatasetTest, ImageEntriesThatAreNotFilesSayWhatTheyAre) {
  writeValid();
  const auto frames = [&](const std::string& second) {
    write("frames.csv", "index,image,stamp_s,altitude_m\n0,0000.jpg,0.0,2\n1," + second + ",0.5,2\n");
  };
  fs::create_directory(dir_ / "adir");
  frames("adir");
  expectError("image 'adir' of frame 1 is a directory, not an image file");
  ASSERT_EQ(::mkfifo((dir_ / "pipe.png").c_str(), 0600), 0);
  frames("pipe.png");
  expectError("image 'pipe.png' of frame 1 is a FIFO (named pipe), not an image file");
  fs::create_symlink("pipe.png", dir_ / "to_pipe.png");
  frames("to_pipe.png");
  expectError("image 'to_pipe.png' of frame 1 is a FIFO (named pipe)");
  fs::create_symlink("gone.png", dir_ / "dangling.png");
  frames("dangling.png");
  expectError("image 'dangling.png' of frame 1 is a symbolic link to a missing file");
  std::string why;
  EXPECT_TRUE(readFrameImage((dir_ / "pipe.png").string(), &why).empty());
  EXPECT_EQ(why, (dir_ / "pipe.png").string() + ": a FIFO (named pipe), not an image file");
  EXPECT_TRUE(readFrameImage((dir_ / "adir").string(), &why).empty());
  EXPECT_EQ(why, (dir_ / "adir").string() + ": a directory, not an image file");
}

// A camera.yaml of another resolution than the images (every frame would be skipped): said before
// a run, from the first image that reads, naming both sizes.
TEST_F(DatasetTest, ACameraOfAnotherSizeThanTheImagesIsSaid) {
  writeValid();  // 0000.jpg does not decode: passed over
  ASSERT_TRUE(cv::imwrite(path("0001.jpg"), cv::Mat(240, 320, CV_8UC3, cv::Scalar(40, 80, 120))));
  EXPECT_EQ(checkCameraFitsImages(loadDataset(dir_.string())), "");  // camera.yaml: 320x240
  writeCameraYaml(path("camera.yaml"), CameraIntrinsics{640, 480, 600.0, 600.0, 320.0, 240.0});
  EXPECT_EQ(checkCameraFitsImages(loadDataset(dir_.string())),
            path("camera.yaml") +
                ": a camera of 640x480 px, but the images are 320x240 px ('0001.jpg', frame 1): every frame would be "
                "skipped; give the camera of these images (a calibration made at another resolution scales "
                "image_width, image_height, fx, fy, cx and cy by the same factor)");
  write("0001.jpg", "x");  // nothing reads: left to the run's counted skips
  EXPECT_EQ(checkCameraFitsImages(loadDataset(dir_.string())), "");
}

TEST(NavFrame, NedAndEnuSwapAsRep103Says) {
  // A heading of 0 (north) in NED is 90 degrees from east, counter-clockwise, in ENU; 2 m north and
  // 1 m east is x 1, y 2 in ENU.
  EXPECT_TRUE(approxEqual(swapEnuNed(Pose2(2.0, 1.0, 0.0)), Pose2(1.0, 2.0, M_PI / 2)));
  EXPECT_TRUE(approxEqual(swapEnuNed(Pose2(0.0, 0.0, M_PI / 2)), Pose2(0.0, 0.0, 0.0)));    // heading east
  EXPECT_TRUE(approxEqual(swapEnuNed(Pose2(0.0, 0.0, M_PI)), Pose2(0.0, 0.0, -M_PI / 2)));  // heading south
  for (const Pose2& p : {Pose2(3.0, -4.0, 2.9), Pose2(-1.0, 0.5, -3.1)})
    EXPECT_TRUE(approxEqual(swapEnuNed(swapEnuNed(p)), p, 1e-12, 1e-12));  // its own inverse
  EXPECT_TRUE(approxEqual(toEnu(Pose2(2.0, 1.0, 0.3), WorldConvention::kEnu), Pose2(2.0, 1.0, 0.3)));
}

TEST_F(DatasetTest, NavFrameYamlPutsNavCsvInAWorldFrameReadAsTheCoreTakesIt) {
  writeValid();
  writeNavCsv(path("nav.csv"), {{0.0, Pose2(2.0, 1.0, 0.0), 0.0, 0.0}, {0.5, Pose2(2.0, 1.5, M_PI / 2), 0.01, 0.001}});
  const std::vector<NavRecord> as_written = loadDataset(dir_.string()).nav;  // no nav_frame.yaml: gt.csv's frame
  EXPECT_TRUE(approxEqual(as_written[1].pose, Pose2(2.0, 1.5, M_PI / 2), 1e-6, 1e-6));
  EXPECT_FALSE(loadDataset(dir_.string()).nav_frame);
  write("nav_frame.yaml", "# the site\nname: site_ned\nconvention: ned\nlatitude_deg: 43.1\nlongitude_deg: 5.9\n");
  const Dataset d = loadDataset(dir_.string());
  ASSERT_TRUE(d.nav_frame);
  EXPECT_EQ(d.nav_frame->name, "site_ned");
  EXPECT_EQ(d.nav_frame->convention, WorldConvention::kNed);
  EXPECT_TRUE(d.nav_frame->has_origin);
  EXPECT_DOUBLE_EQ(d.nav_frame->latitude_deg, 43.1);
  EXPECT_DOUBLE_EQ(d.nav_frame->longitude_deg, 5.9);
  ASSERT_EQ(d.nav.size(), 2u);
  // 2 m north, 1 m east, heading north: ENU (1, 2, pi/2), z-down (1, -2, -pi/2). Then 0.5 m east
  // with a right turn (heading east): ENU (1.5, 2, 0).
  EXPECT_TRUE(approxEqual(zUp(d.nav[0].pose), Pose2(1.0, 2.0, M_PI / 2), 1e-6, 1e-6));
  EXPECT_TRUE(approxEqual(d.nav[0].pose, Pose2(1.0, -2.0, -M_PI / 2), 1e-6, 1e-6));
  EXPECT_TRUE(approxEqual(zUp(d.nav[1].pose), Pose2(1.5, 2.0, 0.0), 1e-6, 1e-6));
  EXPECT_NEAR(d.nav[1].sigma_xy_m, 0.01, 1e-9);
  // The motion the odometry takes: in the camera's image axes (y along the rows: to the right of
  // the direction of travel when the columns point ahead), the move east is along x, the right turn
  // (clockwise seen from above) a positive yaw, as in gt.csv's frame.
  const Pose2 step = between(d.nav[0].pose, d.nav[1].pose);
  EXPECT_TRUE(approxEqual(step, Pose2(0.0, 0.5, M_PI / 2), 1e-6, 1e-6)) << step.x() << " " << step.y();

  // Written and read back; ENU rows are taken as written (then turned z-down).
  const NavFrame enu{"site", WorldConvention::kEnu, false, 0.0, 0.0};
  writeNavFrameYaml(path("nav_frame.yaml"), enu);
  EXPECT_EQ(readNavFrameYaml(path("nav_frame.yaml")), enu);
  EXPECT_TRUE(approxEqual(loadDataset(dir_.string()).nav[1].pose, Pose2(2.0, -1.5, -M_PI / 2), 1e-6, 1e-6));
}

TEST_F(DatasetTest, ABadNavFrameYamlIsRefusedNamingTheKey) {
  writeValid();
  write("nav_frame.yaml", "name: site\nconvention: enu\n");
  expectError("nav_frame.yaml: no nav.csv beside it");
  writeNavCsv(path("nav.csv"), {{0.0, Pose2(), 0.0, 0.0}});
  EXPECT_TRUE(loadDataset(dir_.string()).nav_frame);
  const std::pair<const char*, const char*> cases[] = {
      {"", "empty file (needs name and convention)"},
      {"convention: enu\n", "missing key 'name'"},
      {"name: site\n", "missing key 'convention' (enu or ned)"},
      {"name: site\nconvention: nwu\n", "convention 'nwu' is not enu or ned"},
      {"name: site\nconvention: enu\nlatitude_deg: 43\n", "'latitude_deg' without 'longitude_deg'"},
      {"name: site\nconvention: enu\nlongitude_deg: 5\n", "'longitude_deg' without 'latitude_deg'"},
      {"name: site\nconvention: enu\nlatitude_deg: 91\nlongitude_deg: 5\n", "latitude_deg 91 must be in [-90, 90]"},
      {"name: site\nconvention: enu\nlatitude_deg: 43\nlongitude_deg: 181\n", "longitude_deg 181 must be in"},
      {"name: site\nconvention: enu\nlatitude_deg: \"43\"\nlongitude_deg: 5\n", "bad value for 'latitude_deg'"},
      {"name: site\nconvention: enu\nlatitude_deg: north\nlongitude_deg: 5\n", "bad value for 'latitude_deg'"},
      {"name: /site\nconvention: enu\n", "name '/site' must be a frame id"},
      {"name: site\nconvention: enu\ndatum: wgs84\n", "unknown key 'datum'"},
      {"name: [site\n", "nav_frame YAML"},
  };
  for (const auto& [text, needle] : cases) {
    write("nav_frame.yaml", text);
    expectError(needle);
    expectError(path("nav_frame.yaml"));  // the file is named
  }
}

TEST(Dataset, NotADirectory) { EXPECT_THROW(loadDataset("/nonexistent/uwms"), DatasetError); }

}  // namespace
}  // namespace core
}  // namespace uw_multislam
