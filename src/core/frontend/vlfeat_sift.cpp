#include "uw_multislam/core/frontend/vlfeat_sift.h"

#include <stdexcept>

#ifdef UWMS_HAVE_VLFEAT
#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>
#include <queue>
#include <utility>
#include <vector>

extern "C" {
#include <vl/sift.h>
}
#endif

namespace uw_multislam {
namespace core {

#ifndef UWMS_HAVE_VLFEAT

std::string vlfeatSiftUnavailable() {
  return "this build has no VLFeat (install libvlfeat-dev and rebuild; Debian and Ubuntu ship it for amd64)";
}

cv::Ptr<cv::Feature2D> createVlfeatSift(const FeatureOptions&, int) {
  throw std::invalid_argument("features: VLFeat's SIFT: " + vlfeatSiftUnavailable());
}

#else

std::string vlfeatSiftUnavailable() { return std::string(); }

namespace {

constexpr int kDescriptorSize = 128;
constexpr int kOrientationBins = 8;

/// One oriented keypoint and its descriptor, in OpenCV's conventions (vlfeat_sift.h).
struct Candidate {
  cv::KeyPoint keypoint;
  float descriptor[kDescriptorSize];
};

/// cv::SIFT's contrast of a VLFeat keypoint: the DoG at the interpolated extremum, as VLFeat's
/// vl_sift_detect computes it for its peak threshold (it does not keep it). Valid while `f` holds
/// the keypoint's octave.
double contrastAt(const VlSiftFilt* f, const VlSiftKeypoint& k) {
  const int w = f->octave_width, h = f->octave_height, xo = 1, yo = w, so = w * h;
  const vl_sift_pix* pt = f->dog + xo * k.ix + yo * k.iy + so * (k.is - f->s_min);
  const auto at = [&](int dx, int dy, int ds) { return static_cast<double>(pt[dx * xo + dy * yo + ds * so]); };
  const double xper = std::ldexp(1.0, k.o);
  const double b0 = k.x / xper - k.ix, b1 = k.y / xper - k.iy, b2 = k.s - k.is;
  const double dx = 0.5 * (at(1, 0, 0) - at(-1, 0, 0));
  const double dy = 0.5 * (at(0, 1, 0) - at(0, -1, 0));
  const double ds = 0.5 * (at(0, 0, 1) - at(0, 0, -1));
  return std::abs(at(0, 0, 0) + 0.5 * (dx * b0 + dy * b1 + ds * b2));
}

class VlfeatSift final : public cv::Feature2D {
 public:
  VlfeatSift(const FeatureOptions& o, int max_keypoints) : options_(o), max_keypoints_(max_keypoints) {
    const std::string bad = o.validate();
    if (!bad.empty()) throw std::invalid_argument("features: " + bad);
    if (max_keypoints < 0) throw std::invalid_argument("features: VLFeat's SIFT: max_keypoints must be >= 0");
  }

  int descriptorSize() const override { return kDescriptorSize; }
  int descriptorType() const override { return CV_32F; }
  int defaultNorm() const override { return cv::NORM_L2; }
  cv::String getDefaultName() const override { return "uw_multislam.VlfeatSift"; }

  void detectAndCompute(cv::InputArray image, cv::InputArray mask, std::vector<cv::KeyPoint>& keypoints,
                        cv::OutputArray descriptors, bool use_provided_keypoints) override {
    if (!mask.empty() || use_provided_keypoints)
      throw std::invalid_argument("features: VLFeat's SIFT takes no mask and no given keypoints");
    const cv::Mat grey = image.getMat();
    if (grey.empty() || grey.type() != CV_8UC1)
      throw std::invalid_argument("features: VLFeat's SIFT expects a non-empty 8-bit grey image");
    std::vector<Candidate> kept = detect(grey);
    keypoints.clear();
    keypoints.reserve(kept.size());
    descriptors.create(static_cast<int>(kept.size()), kDescriptorSize, CV_32F);
    cv::Mat d = descriptors.getMat();
    for (std::size_t i = 0; i < kept.size(); ++i) {
      keypoints.push_back(kept[i].keypoint);
      std::copy(kept[i].descriptor, kept[i].descriptor + kDescriptorSize, d.ptr<float>(static_cast<int>(i)));
    }
  }

 private:
  struct FilterDeleter {
    void operator()(VlSiftFilt* f) const { vl_sift_delete(f); }
  };

  /// The filter for images of `size`, made again only when the size changes: its buffers (about
  /// 21 floats per pixel of the first octave) cost more to fault in than to reuse.
  VlSiftFilt* filterFor(cv::Size size) {
    if (filter_ && size == filter_size_) return filter_.get();
    filter_.reset();
    VlSiftFilt* f = vl_sift_new(size.width, size.height, -1, options_.octave_layers, options_.first_octave);
    if (!f) throw std::runtime_error("features: VLFeat's SIFT: out of memory");
    filter_.reset(f);
    filter_size_ = size;
    // cv::SIFT's thresholds on the image in [0, 1]: a DoG extremum of contrast below
    // contrast_threshold / layers is dropped, and so are edges past Lowe's ratio r.
    vl_sift_set_peak_thresh(f, options_.contrast_threshold / options_.octave_layers);
    vl_sift_set_edge_thresh(f, options_.edge_threshold);
    // The base blur: VLFeat's level s has sigma0 k^s with k = 2^(1 / layers) and starts at level
    // -1, so sigma0 = sigma k makes level -1 cv::SIFT's first layer, of blur `sigma` (1.6 in
    // both libraries by default). vl_sift_new derives dsigma0 from sigma0; VLFeat 0.9.21 has no
    // setter for either.
    f->sigma0 = options_.sigma * f->sigmak;
    f->dsigma0 = f->sigma0 * std::sqrt(1.0 - 1.0 / (f->sigmak * f->sigmak));
    return f;
  }

  std::vector<Candidate> detect(const cv::Mat& grey) {
    std::vector<Candidate> all;
    // Too small for one octave's 3 x 3 x 3 neighbourhoods after the border: no keypoint (as cv::SIFT).
    if (std::min(grey.cols, grey.rows) < 8) return all;
    VlSiftFilt* f = filterFor(grey.size());
    cv::Mat image;
    grey.convertTo(image, CV_32F, 1.0 / 255.0);
    if (!image.isContinuous()) image = image.clone();
    // The strongest max_keypoints_ seen so far (a min-heap of responses): a keypoint weaker than
    // the weakest of a full heap is never described, so only about max_keypoints_ descriptors
    // are computed (each octave's keypoints are visited strongest first).
    // std::priority_queue keeps on top what its comparison puts last: the weakest, when a stronger
    // candidate compares "less".
    const auto weakest_on_top = [&](int a, int b) { return stronger(all[a].keypoint, all[b].keypoint); };
    std::priority_queue<int, std::vector<int>, decltype(weakest_on_top)> heap(weakest_on_top);
    std::vector<char> dropped;
    const auto full = [&] { return max_keypoints_ > 0 && static_cast<int>(heap.size()) >= max_keypoints_; };
    float raw[kDescriptorSize];
    // VLFeat caches the gradients of one octave by its index only (grad_o) and does not forget them
    // when a new image starts: the first image's would be used again for the next one's octave of
    // the same index (measured: 15 matches instead of 300 between two frames).
    f->grad_o = f->o_min - 1;
    for (int err = vl_sift_process_first_octave(f, image.ptr<vl_sift_pix>()); err == VL_ERR_OK;
         err = vl_sift_process_next_octave(f)) {
      vl_sift_detect(f);
      const VlSiftKeypoint* keys = vl_sift_get_keypoints(f);
      const int n = vl_sift_get_nkeypoints(f);
      std::vector<std::pair<cv::KeyPoint, int> > octave;
      octave.reserve(static_cast<std::size_t>(n));
      for (int i = 0; i < n; ++i) {
        const VlSiftKeypoint& k = keys[i];
        cv::KeyPoint kp;
        kp.pt = cv::Point2f(k.x, k.y);
        kp.size = 2.0f * k.sigma;  // cv::SIFT's size: the diameter 2 sigma
        kp.response = static_cast<float>(contrastAt(f, k));
        // cv::SIFT's octave packing: octave (-1 = doubled image) in the low byte, layer (1..layers) next.
        kp.octave = (k.o & 255) | ((k.is + 1) << 8);
        octave.emplace_back(kp, i);
      }
      std::sort(octave.begin(), octave.end(), [](const auto& a, const auto& b) { return stronger(a.first, b.first); });
      for (const auto& [kp, i] : octave) {
        if (full() && !stronger(kp, all[heap.top()].keypoint)) break;  // the rest of the octave is weaker
        double angles[4];
        const int na = vl_sift_calc_keypoint_orientations(f, angles, &keys[i]);
        for (int a = 0; a < na; ++a) {
          if (full() && !stronger(kp, all[heap.top()].keypoint)) break;
          Candidate c;
          c.keypoint = kp;
          c.keypoint.angle = static_cast<float>(angles[a] * 180.0 / CV_PI);
          if (c.keypoint.angle >= 360.0f) c.keypoint.angle = 0.0f;
          vl_sift_calc_keypoint_descriptor(f, raw, &keys[i], angles[a]);
          toOpenCvDescriptor(raw, c.descriptor);
          all.push_back(c);
          dropped.push_back(0);
          heap.push(static_cast<int>(all.size()) - 1);
          if (max_keypoints_ > 0 && static_cast<int>(heap.size()) > max_keypoints_) {
            dropped[static_cast<std::size_t>(heap.top())] = 1;
            heap.pop();
          }
        }
      }
    }
    std::vector<Candidate> kept;
    kept.reserve(heap.size());
    for (std::size_t i = 0; i < all.size(); ++i)
      if (!dropped[i]) kept.push_back(all[i]);
    std::stable_sort(kept.begin(), kept.end(),
                     [](const Candidate& a, const Candidate& b) { return stronger(a.keypoint, b.keypoint); });
    return kept;
  }

  /// Descending response; ties by position, then angle: equal images, equal output.
  static bool stronger(const cv::KeyPoint& a, const cv::KeyPoint& b) {
    if (a.response != b.response) return a.response > b.response;
    if (a.pt.y != b.pt.y) return a.pt.y < b.pt.y;
    if (a.pt.x != b.pt.x) return a.pt.x < b.pt.x;
    return a.angle < b.angle;
  }

  /// VLFeat's descriptor (a unit vector, clipped at 0.2 and renormalised, like Lowe's) as cv::SIFT
  /// gives it. Both lay the 4 x 4 x 8 histogram out row bin, column bin, orientation bin, with the
  /// same rotated sample grid; but VLFeat measures a gradient's orientation from x towards y (image y
  /// down) and OpenCV from x towards -y (its dy is I(y-1) - I(y+1)), relative to the keypoint's own
  /// angle in each convention. So VLFeat's orientation bin t is OpenCV's bin (8 - t) mod 8. The
  /// values are cv::SIFT's: x 512, saturated at 255, rounded.
  static void toOpenCvDescriptor(const float* vl, float* cv_out) {
    for (int cell = 0; cell < kDescriptorSize / kOrientationBins; ++cell) {
      const float* in = vl + cell * kOrientationBins;
      float* out = cv_out + cell * kOrientationBins;
      for (int t = 0; t < kOrientationBins; ++t) {
        const float v = std::min(255.0f, std::round(512.0f * in[t]));
        out[(kOrientationBins - t) % kOrientationBins] = v;
      }
    }
  }

  FeatureOptions options_;
  int max_keypoints_;
  std::unique_ptr<VlSiftFilt, FilterDeleter> filter_;
  cv::Size filter_size_;
};

}  // namespace

cv::Ptr<cv::Feature2D> createVlfeatSift(const FeatureOptions& options, int max_keypoints) {
  return cv::makePtr<VlfeatSift>(options, max_keypoints);
}

#endif  // UWMS_HAVE_VLFEAT

}  // namespace core
}  // namespace uw_multislam
