// The keyframe image the session store keeps (core/store/keyframe_image.h, config `store`).
#include <gtest/gtest.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <stdexcept>
#include <string>

#include "../../common/rendered_seabed.h"
#include "uw_multislam/core/session/slam_config.h"
#include "uw_multislam/core/store/keyframe_image.h"

namespace uw_multislam {
namespace core {
namespace {

class KeyframeImageTest : public testing_util::RenderedSeabedTest {};

cv::Mat decode(const std::vector<std::uint8_t>& jpeg) { return cv::imdecode(jpeg, cv::IMREAD_UNCHANGED); }

TEST_F(KeyframeImageTest, LongestSideIsTheConfiguredOneAndGreyJpeg) {
  const cv::Mat frame = render(Pose2(4.0, 3.0, 0.2), 2.0);  // 320 x 240 BGR
  ASSERT_EQ(frame.channels(), 3);
  KeyframeImageOptions o;
  o.max_side_px = 160;
  const std::vector<std::uint8_t> jpeg = encodeKeyframeImage(frame, o);
  ASSERT_GE(jpeg.size(), 4u);
  EXPECT_EQ(jpeg[0], 0xff);  // JPEG SOI
  EXPECT_EQ(jpeg[1], 0xd8);
  const cv::Mat img = decode(jpeg);
  EXPECT_EQ(img.size(), cv::Size(160, 120));
  EXPECT_EQ(img.channels(), 1);
  // A portrait frame: the rows are the longest side.
  const cv::Mat tall = frame.t();
  EXPECT_EQ(decode(encodeKeyframeImage(tall, o)).size(), cv::Size(120, 160));
}

TEST_F(KeyframeImageTest, NeverEnlargedAndNoneWhenOff) {
  const cv::Mat frame = render(Pose2(4.0, 3.0, 0.0), 2.0);
  KeyframeImageOptions o;
  o.max_side_px = 640;
  EXPECT_EQ(decode(encodeKeyframeImage(frame, o)).size(), cv::Size(320, 240));
  o.max_side_px = 0;
  EXPECT_TRUE(encodeKeyframeImage(frame, o).empty());
  o.max_side_px = 320;
  EXPECT_TRUE(encodeKeyframeImage(cv::Mat(), o).empty());
}

TEST_F(KeyframeImageTest, QualityTradesBytesForFidelity) {
  const cv::Mat frame = render(Pose2(5.0, 4.0, 0.4), 2.0);
  cv::Mat grey;
  cv::cvtColor(frame, grey, cv::COLOR_BGR2GRAY);
  KeyframeImageOptions low, high;
  low.max_side_px = high.max_side_px = 320;
  low.jpeg_quality = 40;
  high.jpeg_quality = 95;
  const std::vector<std::uint8_t> a = encodeKeyframeImage(frame, low), b = encodeKeyframeImage(frame, high);
  EXPECT_LT(a.size() * 2, b.size());
  const double psnr_low = cv::PSNR(decode(a), grey), psnr_high = cv::PSNR(decode(b), grey);
  EXPECT_GT(psnr_high, psnr_low + 3.0) << psnr_low << " " << psnr_high;
  EXPECT_GT(psnr_high, 35.0);
}

TEST(KeyframeImageConfig, KeysReadValidatedAndWritten) {
  const SlamConfig defaults;
  EXPECT_EQ(defaults.store_image.max_side_px, 320);
  EXPECT_EQ(defaults.store_image.jpeg_quality, 75);
  const SlamConfig c = slamConfigFromYaml("store: {image_max_side_px: 160, image_jpeg_quality: 75}\n");
  EXPECT_EQ(c.store_image.max_side_px, 160);
  EXPECT_EQ(c.store_image.jpeg_quality, 75);
  EXPECT_EQ(slamConfigToYaml(slamConfigFromYaml(slamConfigToYaml(c))), slamConfigToYaml(c));
  EXPECT_EQ(slamConfigFromYaml("store: {image_max_side_px: 0}\n").store_image.max_side_px, 0);
  for (const std::string bad :
       {"store: {image_max_side_px: 8}\n", "store: {image_max_side_px: -1}\n", "store: {image_jpeg_quality: 0}\n",
        "store: {image_jpeg_quality: 101}\n", "store: {image_size: 3}\n"}) {
    try {
      slamConfigFromYaml(bad);
      ADD_FAILURE() << "accepted: " << bad;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("store"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace core
}  // namespace uw_multislam
