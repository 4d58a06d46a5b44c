// sensor_msgs/CompressedImage -> sensor_msgs/Image, the odometry's built-in decoder when
// image_transport has no `compressed` plugin (ros/sensor_conversions.h): lossless PNG gives the
// same pixels, JPEG the same within a measured bound, bad input a refusal of the right kind.
#include <gtest/gtest.h>

#include <sensor_msgs/image_encodings.h>

#include <boost/make_shared.hpp>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <string>
#include <vector>

#include "../common/rendered_seabed.h"
#include "uw_multislam/ros/image_input.h"
#include "uw_multislam/ros/sensor_conversions.h"

namespace uw_multislam {
namespace {

namespace rc = ros_conversions;
namespace enc = sensor_msgs::image_encodings;

sensor_msgs::CompressedImage compressed(const cv::Mat& image, const std::string& extension, const std::string& format,
                                        const std::vector<int>& params = {}) {
  sensor_msgs::CompressedImage m;
  m.header.stamp = ros::Time(1700000123, 456000000);
  m.header.frame_id = "camera";
  m.header.seq = 7;
  m.format = format;
  EXPECT_TRUE(cv::imencode(extension, image, m.data, params)) << extension;
  return m;
}

// The decoded message's pixels as a Mat (a view of its data).
cv::Mat pixels(const sensor_msgs::Image& m, int type) {
  return cv::Mat(static_cast<int>(m.height), static_cast<int>(m.width), type, const_cast<std::uint8_t*>(m.data.data()),
                 m.step);
}

class CompressedImages : public testing_util::RenderedSeabedTest {
 protected:
  void SetUp() override {
    bgr_ = render(core::Pose2(4.0, 3.0, 0.3), 1.6);
    ASSERT_EQ(bgr_.type(), CV_8UC3);
    cv::cvtColor(bgr_, grey_, cv::COLOR_BGR2GRAY);
  }
  sensor_msgs::ImagePtr decode(const sensor_msgs::CompressedImage& m) {
    sensor_msgs::ImagePtr out;
    std::string why;
    rc::ImageRefusal kind = rc::ImageRefusal::kEncoding;
    EXPECT_TRUE(rc::imageFromCompressedMsg(m, &out, &why, &kind)) << m.format << ": " << why;
    EXPECT_EQ(kind, rc::ImageRefusal::kNone);
    if (!out) return boost::make_shared<sensor_msgs::Image>();
    EXPECT_EQ(out->header.stamp, m.header.stamp);
    EXPECT_EQ(out->header.frame_id, m.header.frame_id);
    EXPECT_EQ(out->header.seq, m.header.seq);
    return out;
  }
  void expectRefused(const sensor_msgs::CompressedImage& m, rc::ImageRefusal expected, const std::string& words) {
    sensor_msgs::ImagePtr out;
    std::string why;
    rc::ImageRefusal kind = rc::ImageRefusal::kNone;
    EXPECT_FALSE(rc::imageFromCompressedMsg(m, &out, &why, &kind)) << m.format;
    EXPECT_EQ(rc::imageRefusalName(kind), rc::imageRefusalName(expected)) << why;
    EXPECT_NE(why.find(words), std::string::npos) << why;
    EXPECT_FALSE(out);
  }

  cv::Mat bgr_, grey_;
};

TEST_F(CompressedImages, PngGivesTheSamePixels) {
  // As compressed_image_transport writes them: colour as BGR with its target, grey without.
  const auto colour = decode(compressed(bgr_, ".png", "rgb8; png compressed bgr8"));
  EXPECT_EQ(colour->encoding, enc::BGR8);
  EXPECT_EQ(cv::norm(pixels(*colour, CV_8UC3), bgr_, cv::NORM_INF), 0.0);
  const auto grey = decode(compressed(grey_, ".png", "mono8; png compressed "));
  EXPECT_EQ(grey->encoding, enc::MONO8);
  EXPECT_EQ(cv::norm(pixels(*grey, CV_8UC1), grey_, cv::NORM_INF), 0.0);
  // Plain "png" (the message definition's values); upper case too.
  EXPECT_EQ(decode(compressed(grey_, ".png", "png"))->encoding, enc::MONO8);
  EXPECT_EQ(decode(compressed(bgr_, ".png", "PNG"))->encoding, enc::BGR8);

  // 16 bits (a 12-bit sensor in mono16) stay 16 bits; imageFromMsg then scales them as for a raw mono16.
  cv::Mat twelve;
  grey_.convertTo(twelve, CV_16U, 16.0);
  const auto sixteen = decode(compressed(twelve, ".png", "mono16; png compressed "));
  EXPECT_EQ(sixteen->encoding, enc::MONO16);
  EXPECT_EQ(cv::norm(pixels(*sixteen, CV_16UC1), twelve, cv::NORM_INF), 0.0);
  cv::Mat eight;
  ASSERT_TRUE(rc::imageFromMsg(sixteen, &eight));
  cv::Mat expected;
  twelve.convertTo(expected, CV_8U, 255.0 / 4095.0);
  EXPECT_LE(cv::norm(eight, expected, cv::NORM_INF), 0.0);

  // A Bayer mosaic keeps its encoding, so imageFromMsg debayers it.
  EXPECT_EQ(decode(compressed(grey_, ".png", "bayer_rggb8; png compressed "))->encoding, enc::BAYER_RGGB8);
  // A colour encoding before compression but one channel decoded: grey by the data.
  EXPECT_EQ(decode(compressed(grey_, ".png", "bgr8; png compressed bgr8"))->encoding, enc::MONO8);
}

TEST_F(CompressedImages, TheOdometrysImageOfACompressedMessageOwnsItsPixels) {
  // The message decoded inside imageFromInput is gone when it returns: the image must not point into it.
  core::CameraIntrinsics camera;
  camera.width = bgr_.cols;
  camera.height = bgr_.rows;
  for (const auto& [image, format] : {std::pair<cv::Mat, std::string>{bgr_, "bgr8; png compressed bgr8"},
                                      std::pair<cv::Mat, std::string>{grey_, "mono8; png compressed "}}) {
    ros_inputs::ImageMsg m;
    m.compressed = boost::make_shared<sensor_msgs::CompressedImage>(compressed(image, ".png", format));
    cv::Mat out;
    std::string why;
    ASSERT_TRUE(ros_inputs::imageFromInput(m, camera, rc::kDefaultMaxImagePixels, &out, &why, nullptr)) << why;
    EXPECT_NE(out.u, nullptr) << format;  // a buffer of its own (reference-counted), not a view
    EXPECT_EQ(cv::norm(out, image, cv::NORM_INF), 0.0) << format;
  }
}

TEST_F(CompressedImages, JpegGivesTheSamePixelsWithinTheCodecsError) {
  // Measured on this 320 x 240 seabed at quality 90 (OpenCV 4.6, libjpeg-turbo): mean absolute
  // error 1.30 (grey) / 1.93 (colour) grey levels, at most 12 (grey) / 34 (colour). A decoder that
  // swapped channels, shifted rows or lost the data would be far off (> 10 mean).
  const std::vector<int> q90 = {cv::IMWRITE_JPEG_QUALITY, 90};
  const auto grey = decode(compressed(grey_, ".jpg", "mono8; jpeg compressed ", q90));
  ASSERT_EQ(grey->encoding, enc::MONO8);
  const cv::Mat g = pixels(*grey, CV_8UC1);
  const double grey_mean = cv::norm(g, grey_, cv::NORM_L1) / grey_.total();
  const auto colour = decode(compressed(bgr_, ".jpg", "bgr8; jpeg compressed bgr8", q90));
  ASSERT_EQ(colour->encoding, enc::BGR8);
  const cv::Mat c = pixels(*colour, CV_8UC3);
  const double colour_mean = cv::norm(c, bgr_, cv::NORM_L1) / bgr_.total() / 3.0;
  std::printf("jpeg q90: mean abs error grey %.3f colour %.3f, max grey %.0f colour %.0f\n", grey_mean, colour_mean,
              cv::norm(g, grey_, cv::NORM_INF), cv::norm(c, bgr_, cv::NORM_INF));
  EXPECT_LT(grey_mean, 2.0);
  EXPECT_LT(colour_mean, 2.5);
  EXPECT_LE(cv::norm(g, grey_, cv::NORM_INF), 20.0);
  // Each channel on its own (a B/R swap keeps the overall mean of a greyish seabed low).
  std::vector<cv::Mat> got, want;
  cv::split(c, got);
  cv::split(bgr_, want);
  for (int i = 0; i < 3; ++i) EXPECT_LT(cv::norm(got[i], want[i], cv::NORM_L1) / bgr_.total(), 3.0) << "channel " << i;
  // Other spellings of the format.
  EXPECT_EQ(decode(compressed(bgr_, ".jpg", "jpeg"))->encoding, enc::BGR8);
  EXPECT_EQ(decode(compressed(grey_, ".jpg", "mono8; jpeg compressed mono8"))->encoding, enc::MONO8);
  EXPECT_EQ(decode(compressed(bgr_, ".jpg", "rgb8; jpeg compressed bgr8"))->encoding, enc::BGR8);
  // The result takes the raw path: grey shared, the size the camera's.
  cv::Mat raw;
  std::string why;
  ASSERT_TRUE(rc::imageFromMsg(grey, &raw, &why)) << why;
  EXPECT_EQ(raw.size(), grey_.size());
}

TEST_F(CompressedImages, CorruptDataIsRefusedAsCorrupt) {
  const auto jpeg = compressed(bgr_, ".jpg", "bgr8; jpeg compressed bgr8");
  const auto png = compressed(grey_, ".png", "mono8; png compressed ");

  auto garbage = jpeg;
  for (std::size_t i = 0; i < garbage.data.size(); ++i) garbage.data[i] = static_cast<std::uint8_t>(i * 37 + 11);
  expectRefused(garbage, rc::ImageRefusal::kCorrupt, "not JPEG data");
  auto png_as_jpeg = png;
  png_as_jpeg.format = "jpeg";
  expectRefused(png_as_jpeg, rc::ImageRefusal::kCorrupt, "not JPEG data");

  auto cut = jpeg;
  cut.data.resize(cut.data.size() / 2);  // libjpeg alone would only warn and fill grey
  expectRefused(cut, rc::ImageRefusal::kCorrupt, "truncated JPEG");
  ASSERT_TRUE(rc::isTruncatedJpeg(cut.data));
  EXPECT_FALSE(rc::isTruncatedJpeg(jpeg.data));

  // Start and end markers intact, the headers between them zeroed: libjpeg gives up.
  auto no_headers = jpeg;
  std::fill(no_headers.data.begin() + 4, no_headers.data.begin() + 600, 0);
  expectRefused(no_headers, rc::ImageRefusal::kCorrupt, "OpenCV cannot decode");

  auto png_cut = png;
  png_cut.data.resize(png_cut.data.size() / 2);
  expectRefused(png_cut, rc::ImageRefusal::kCorrupt, "OpenCV cannot decode");
  auto png_flipped = png;  // a byte of the image data flipped: the chunk's CRC fails
  png_flipped.data[png_flipped.data.size() / 2] ^= 0x5A;
  expectRefused(png_flipped, rc::ImageRefusal::kCorrupt, "OpenCV cannot decode");
}

TEST_F(CompressedImages, EmptyDataAndUnknownFormatsAreRefused) {
  auto empty = compressed(grey_, ".png", "mono8; png compressed ");
  empty.data.clear();
  expectRefused(empty, rc::ImageRefusal::kEmpty, "no data");
  for (const std::string format : {"tiff", "h264", "", "16UC1; compressedDepth png", "mono8; webp compressed "}) {
    expectRefused(compressed(grey_, ".png", format), rc::ImageRefusal::kEncoding, "'" + format + "'");
  }
  EXPECT_EQ(rc::imageRefusalName(rc::ImageRefusal::kCorrupt), "corrupt");
}

TEST_F(CompressedImages, ImagesLargerThanTheLimitAreRefusedFromTheirHeaderBeforeDecoding) {
  const std::uint64_t pixels = static_cast<std::uint64_t>(grey_.cols) * grey_.rows;
  for (const auto& m :
       {compressed(grey_, ".png", "mono8; png compressed "), compressed(bgr_, ".jpg", "bgr8; jpeg compressed bgr8")}) {
    sensor_msgs::ImagePtr out;
    std::string why;
    rc::ImageRefusal kind = rc::ImageRefusal::kNone;
    EXPECT_FALSE(rc::imageFromCompressedMsg(m, &out, &why, &kind, pixels - 1)) << m.format;
    EXPECT_EQ(rc::imageRefusalName(kind), "too_large") << why;
    EXPECT_NE(why.find(std::to_string(grey_.cols) + "x" + std::to_string(grey_.rows)), std::string::npos) << why;
    EXPECT_FALSE(out);
    EXPECT_TRUE(rc::imageFromCompressedMsg(m, &out, &why, &kind, pixels)) << why;
  }
  // Headers that claim a huge image (the data behind them is the small one): refused as too
  // large by the default limit, before the decoder would allocate it.
  auto png = compressed(grey_, ".png", "mono8; png compressed ");
  for (int i : {16, 20}) {  // IHDR width, height (big-endian): 100000 x 100000
    png.data[i] = 0x00, png.data[i + 1] = 0x01, png.data[i + 2] = 0x86, png.data[i + 3] = 0xA0;
  }
  expectRefused(png, rc::ImageRefusal::kTooLarge, "100000x100000");
  auto jpeg = compressed(bgr_, ".jpg", "bgr8; jpeg compressed bgr8");
  std::size_t sof = 2;  // the first SOFn marker: precision, then height and width (big-endian)
  while (sof + 9 < jpeg.data.size() &&
         !(jpeg.data[sof] == 0xFF && (jpeg.data[sof + 1] & 0xF0) == 0xC0 && jpeg.data[sof + 1] != 0xC4 &&
           jpeg.data[sof + 1] != 0xC8 && jpeg.data[sof + 1] != 0xCC))
    sof += 2 + (jpeg.data[sof + 2] << 8 | jpeg.data[sof + 3]);
  ASSERT_LT(sof + 9, jpeg.data.size());
  for (std::size_t i : {sof + 5, sof + 7}) jpeg.data[i] = 0xEA, jpeg.data[i + 1] = 0x60;  // 60000 x 60000
  expectRefused(jpeg, rc::ImageRefusal::kTooLarge, "60000x60000");
}

TEST_F(CompressedImages, UnusualDecodedTypesAreMappedOrRefused) {
  cv::Mat bgra;
  cv::cvtColor(bgr_, bgra, cv::COLOR_BGR2BGRA);
  const auto with_alpha = decode(compressed(bgra, ".png", "png"));
  EXPECT_EQ(with_alpha->encoding, enc::BGRA8);
  cv::Mat out;
  ASSERT_TRUE(rc::imageFromMsg(with_alpha, &out));
  EXPECT_EQ(cv::norm(out, bgr_, cv::NORM_INF), 0.0);  // alpha dropped by the raw path
  cv::Mat bgr16;
  bgr_.convertTo(bgr16, CV_16U, 257.0);
  EXPECT_EQ(decode(compressed(bgr16, ".png", "bgr16; png compressed bgr16"))->encoding, enc::BGR16);
}

}  // namespace
}  // namespace uw_multislam
