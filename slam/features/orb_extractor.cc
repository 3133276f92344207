#include "slam/features/orb_extractor.h"

#include <glog/logging.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <queue>
#include <random>
#include <unordered_set>

namespace twist::features {
namespace {

constexpr int kHalfPatch = 15;      // orientation patch radius (31 px patch)
constexpr int kEdge = 19;           // keypoints kept this far from the level border
constexpr int kPatternRadius = 13;  // BRIEF test points lie in this disc
constexpr int kCellSize = 32;       // FAST threshold fallback cells (px)
// Added to a favoured corner's response while the level is distributed.
constexpr float kFavoured = 1e4f;

struct QuadNode {
  int x0, y0, x1, y1;
  std::vector<int> idx;
};

// Uniform (0, 1) from a 64-bit Mersenne twister: mt19937_64's output sequence
// is fixed by the standard, so the pattern is the same on every platform.
double Uniform01(std::mt19937_64* rng) {
  return (static_cast<double>((*rng)() >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

// Quadtree distribution of a level's corners: split the most crowded node
// until there are `target` nodes or no node can be split, then keep the
// strongest corner of each (at most `target`, the strongest first).
std::vector<cv::KeyPoint> SpreadCorners(const std::vector<cv::KeyPoint>& cand,
                                        int target,
                                        int cols,
                                        int rows) {
  if (cand.empty() || target <= 0) return {};
  std::vector<QuadNode> nodes;
  const int x0 = kEdge, x1 = cols - kEdge, y0 = kEdge, y1 = rows - kEdge;
  const int w = x1 - x0, h = y1 - y0;
  const int n_root = std::max(1, static_cast<int>(std::lround(static_cast<double>(w) / h)));
  for (int i = 0; i < n_root; ++i) {
    nodes.push_back({x0 + w * i / n_root, y0, x0 + w * (i + 1) / n_root, y1, {}});
  }
  for (int i = 0; i < static_cast<int>(cand.size()); ++i) {
    const int r = std::min(n_root - 1, static_cast<int>((cand[i].pt.x - x0) * n_root / w));
    nodes[std::max(r, 0)].idx.push_back(i);
  }
  // (count, -creation order) max-heap: deterministic ties.
  using Entry = std::pair<int, int>;
  std::priority_queue<Entry> heap;
  std::vector<char> alive(nodes.size(), 1);
  int num_alive = 0;
  for (int i = 0; i < static_cast<int>(nodes.size()); ++i) {
    if (nodes[i].idx.empty()) {
      alive[i] = 0;
      continue;
    }
    ++num_alive;
    heap.push({static_cast<int>(nodes[i].idx.size()), -i});
  }
  while (num_alive < target && !heap.empty()) {
    const int ni = -heap.top().second;
    heap.pop();
    QuadNode node = std::move(nodes[ni]);
    if (node.idx.size() <= 1 || node.x1 - node.x0 < 2 || node.y1 - node.y0 < 2) {
      nodes[ni] = std::move(node);  // a leaf, stays alive, never split again
      continue;
    }
    alive[ni] = 0;
    --num_alive;
    const int mx = (node.x0 + node.x1) / 2, my = (node.y0 + node.y1) / 2;
    QuadNode ch[4] = {{node.x0, node.y0, mx, my, {}},
                      {mx, node.y0, node.x1, my, {}},
                      {node.x0, my, mx, node.y1, {}},
                      {mx, my, node.x1, node.y1, {}}};
    for (int i : node.idx) {
      const cv::Point2f& p = cand[i].pt;
      ch[(p.x >= mx ? 1 : 0) + (p.y >= my ? 2 : 0)].idx.push_back(i);
    }
    for (auto& c : ch) {
      if (c.idx.empty()) continue;
      const int id = static_cast<int>(nodes.size());
      const int count = static_cast<int>(c.idx.size());
      nodes.push_back(std::move(c));
      alive.push_back(1);
      ++num_alive;
      heap.push({count, -id});
    }
  }
  std::vector<cv::KeyPoint> kept;
  kept.reserve(num_alive);
  for (size_t n = 0; n < nodes.size(); ++n) {
    if (!alive[n]) continue;
    int best = nodes[n].idx[0];
    for (int i : nodes[n].idx) {
      if (cand[i].response > cand[best].response) best = i;
    }
    kept.push_back(cand[best]);
  }
  if (static_cast<int>(kept.size()) > target) {
    std::stable_sort(kept.begin(), kept.end(), [](const cv::KeyPoint& a, const cv::KeyPoint& b) {
      return a.response > b.response;
    });
    kept.resize(target);
  }
  return kept;
}

}  // namespace

absl::Status OrbOptions::Validate() const {
  if (num_features < 50 || num_features > 50000) {
    return absl::InvalidArgumentError("num_features must be in [50, 50000]");
  }
  if (num_levels < 1 || num_levels > 16) {
    return absl::InvalidArgumentError("num_levels must be in [1, 16]");
  }
  if (!(scale_factor > 1.0 && scale_factor <= 2.0)) {
    return absl::InvalidArgumentError("scale_factor must be in (1, 2]");
  }
  if (fast_threshold < 1 || fast_threshold > 200 || min_fast_threshold < 1 ||
      min_fast_threshold > fast_threshold) {
    return absl::InvalidArgumentError(
        "FAST thresholds must satisfy 1 <= min_fast_threshold <= fast_threshold <= 200");
  }
  return absl::OkStatus();
}

ScalePyramid ScalePyramid::Create(int num_levels, double scale_factor) {
  ScalePyramid p;
  p.scale_factor = scale_factor;
  p.log_scale_factor = std::log(scale_factor);
  double s = 1.0;
  for (int l = 0; l < num_levels; ++l) {
    p.scale.push_back(static_cast<float>(s));
    p.inv_scale.push_back(static_cast<float>(1.0 / s));
    p.sigma2.push_back(static_cast<float>(s * s));
    p.inv_sigma2.push_back(static_cast<float>(1.0 / (s * s)));
    s *= scale_factor;
  }
  return p;
}

int DescriptorDistance(const uint8_t* a, const uint8_t* b) {
  // SWAR popcount: the build does not assume the POPCNT instruction, and
  // __builtin_popcountll would then call a slow libgcc routine.
  uint64_t acc = 0;
  for (int i = 0; i < 4; ++i) {
    uint64_t x, y;
    std::memcpy(&x, a + 8 * i, 8);
    std::memcpy(&y, b + 8 * i, 8);
    uint64_t v = x ^ y;
    v = v - ((v >> 1) & 0x5555555555555555ULL);
    v = (v & 0x3333333333333333ULL) + ((v >> 2) & 0x3333333333333333ULL);
    v = (v + (v >> 4)) & 0x0f0f0f0f0f0f0f0fULL;
    acc += v;  // per-byte counts (each <= 8, four words sum to <= 32 per byte)
  }
  return static_cast<int>((acc * 0x0101010101010101ULL) >> 56);
}

OrbExtractor::OrbExtractor(const OrbOptions& options)
    : options_(options), pyramid_(ScalePyramid::Create(options.num_levels, options.scale_factor)) {
  CHECK(options_.Validate().ok()) << options_.Validate().message();
  // Features per level: geometric series so that the density per image area
  // is about equal across levels.
  const int L = options_.num_levels;
  const double f = 1.0 / options_.scale_factor;
  double per_level = options_.num_features * (1.0 - f) / (1.0 - std::pow(f, L));
  int total = 0;
  for (int l = 0; l < L - 1; ++l) {
    const int n = static_cast<int>(std::lround(per_level));
    features_per_level_.push_back(n);
    total += n;
    per_level *= f;
  }
  features_per_level_.push_back(std::max(options_.num_features - total, 0));

  umax_.resize(kHalfPatch + 1);
  for (int v = 0; v <= kHalfPatch; ++v) {
    umax_[v] = static_cast<int>(std::floor(std::sqrt(kHalfPatch * kHalfPatch - v * v + 0.5)));
  }

  // Gaussian test pattern, sigma = patch / 5 (BRIEF G II), inside the disc.
  std::mt19937_64 rng(options_.pattern_seed);
  const double sigma = 31.0 / 5.0;
  auto sample = [&](int8_t* x, int8_t* y) {
    while (true) {
      const double u1 = Uniform01(&rng), u2 = Uniform01(&rng);
      const double r = std::sqrt(-2.0 * std::log(u1)) * sigma;
      const double a = 2.0 * M_PI * u2;
      const int xi = static_cast<int>(std::lround(r * std::cos(a)));
      const int yi = static_cast<int>(std::lround(r * std::sin(a)));
      if (xi * xi + yi * yi <= kPatternRadius * kPatternRadius) {
        *x = static_cast<int8_t>(xi);
        *y = static_cast<int8_t>(yi);
        return;
      }
    }
  };
  pattern_.resize(8 * kDescriptorBytes);
  for (auto& t : pattern_) {
    do {
      sample(&t[0], &t[1]);
      sample(&t[2], &t[3]);
    } while (t[0] == t[2] && t[1] == t[3]);
  }
  // The pattern steered to each orientation bin (the rotation keeps the
  // points inside the disc, so inside the level's border).
  rotated_pattern_.resize(kAngleBins);
  for (int bin = 0; bin < kAngleBins; ++bin) {
    const double a = 2.0 * M_PI * bin / kAngleBins;
    const double c = std::cos(a), s = std::sin(a);
    auto& rot = rotated_pattern_[bin];
    rot.resize(pattern_.size());
    for (size_t t = 0; t < pattern_.size(); ++t) {
      for (int p = 0; p < 2; ++p) {
        const double x = pattern_[t][2 * p], y = pattern_[t][2 * p + 1];
        rot[t][2 * p] = static_cast<int8_t>(std::lround(x * c - y * s));
        rot[t][2 * p + 1] = static_cast<int8_t>(std::lround(x * s + y * c));
      }
    }
  }
}

void OrbExtractor::BuildPyramid(const cv::Mat& image, std::vector<cv::Mat>* levels) const {
  levels->resize(options_.num_levels);
  (*levels)[0] = image;
  for (int l = 1; l < options_.num_levels; ++l) {
    const float inv = pyramid_.inv_scale[l];
    const cv::Size sz(static_cast<int>(std::lround(image.cols * inv)),
                      static_cast<int>(std::lround(image.rows * inv)));
    cv::resize((*levels)[l - 1], (*levels)[l], sz, 0, 0, cv::INTER_LINEAR);
  }
}

float OrbExtractor::IntensityCentroidAngle(const cv::Mat& image, const cv::Point2f& pt) const {
  const int cx = cvRound(pt.x), cy = cvRound(pt.y);
  const uint8_t* center = image.ptr<uint8_t>(cy) + cx;
  const int step = static_cast<int>(image.step1());
  int m01 = 0, m10 = 0;
  for (int u = -kHalfPatch; u <= kHalfPatch; ++u) m10 += u * center[u];
  for (int v = 1; v <= kHalfPatch; ++v) {
    int v_sum = 0;
    const int d = umax_[v];
    for (int u = -d; u <= d; ++u) {
      const int val_plus = center[u + v * step], val_minus = center[u - v * step];
      v_sum += (val_plus - val_minus);
      m10 += u * (val_plus + val_minus);
    }
    m01 += v * v_sum;
  }
  float angle = static_cast<float>(std::atan2(static_cast<double>(m01), m10) * 180.0 / M_PI);
  if (angle < 0) angle += 360.f;
  return angle;
}

void OrbExtractor::ExtractLevel(const cv::Mat& img,
                                const cv::Mat& mask,
                                int level,
                                int target,
                                std::vector<cv::KeyPoint>* out) const {
  out->clear();
  if (target <= 0 || img.cols <= 2 * kEdge || img.rows <= 2 * kEdge) return;
  // Strong corners over the whole level; the weak threshold only in cells
  // where the strong one found nothing (FAST at the low threshold everywhere
  // would cost several times more).
  const cv::Rect roi(kEdge - 3, kEdge - 3, img.cols - 2 * kEdge + 6, img.rows - 2 * kEdge + 6);
  std::vector<cv::KeyPoint> all;
  cv::FAST(img(roi), all, options_.fast_threshold, true);
  const int gx = (roi.width + kCellSize - 1) / kCellSize;
  const int gy = (roi.height + kCellSize - 1) / kCellSize;
  std::vector<char> has_strong(gx * gy, 0);
  for (const cv::KeyPoint& kp : all) {
    has_strong[static_cast<int>(kp.pt.y) / kCellSize * gx + static_cast<int>(kp.pt.x) / kCellSize] =
        1;
  }
  for (auto& kp : all) kp.pt += cv::Point2f(static_cast<float>(roi.x), static_cast<float>(roi.y));
  if (options_.min_fast_threshold < options_.fast_threshold) {
    std::vector<cv::KeyPoint> weak;
    for (int cy = 0; cy < gy; ++cy) {
      for (int cx = 0; cx < gx; ++cx) {
        if (has_strong[cy * gx + cx]) continue;
        // Cell plus the 3-pixel FAST margin, clipped to the level ROI.
        const int x0 = roi.x + cx * kCellSize - 3, y0 = roi.y + cy * kCellSize - 3;
        const int x1 = std::min(roi.x + roi.width, roi.x + (cx + 1) * kCellSize + 3);
        const int y1 = std::min(roi.y + roi.height, roi.y + (cy + 1) * kCellSize + 3);
        if (x1 - x0 < 8 || y1 - y0 < 8) continue;
        const cv::Rect cell(std::max(x0, roi.x), std::max(y0, roi.y), 0, 0);
        const cv::Rect r(cell.x, cell.y, x1 - cell.x, y1 - cell.y);
        weak.clear();
        cv::FAST(img(r), weak, options_.min_fast_threshold, true);
        for (cv::KeyPoint kp : weak) {
          kp.pt += cv::Point2f(static_cast<float>(r.x), static_cast<float>(r.y));
          // Keep only corners of this cell (the margin belongs to neighbours).
          const int kx = static_cast<int>(kp.pt.x) - roi.x, ky = static_cast<int>(kp.pt.y) - roi.y;
          if (kx / kCellSize != cx || ky / kCellSize != cy) continue;
          all.push_back(kp);
        }
      }
    }
  }
  std::vector<cv::KeyPoint> cand;
  cand.reserve(all.size());
  for (cv::KeyPoint kp : all) {
    if (kp.pt.x < kEdge || kp.pt.y < kEdge || kp.pt.x >= img.cols - kEdge ||
        kp.pt.y >= img.rows - kEdge) {
      continue;
    }
    if (!mask.empty()) {
      const uint8_t m = mask.at<uint8_t>(cvRound(kp.pt.y), cvRound(kp.pt.x));
      if (m == 0) continue;
      if (m >= 128) kp.response += kFavoured;  // favoured region wins within its cell
    }
    cand.push_back(kp);
  }
  if (cand.empty()) return;

  std::vector<cv::KeyPoint> kept = SpreadCorners(cand, target, img.cols, img.rows);
  // With favoured_on_top, favoured corners come on top of the budget: those
  // that won their nodes in the spread over all corners are kept, and the
  // other corners are spread again without them, over the whole budget (an
  // object's keypoints do not take the camera's).
  if (options_.favoured_on_top && std::any_of(cand.begin(), cand.end(), [](const cv::KeyPoint& kp) {
        return kp.response >= kFavoured;
      })) {
    std::vector<cv::KeyPoint> favoured, others;
    std::unordered_set<int64_t> in_budget;   // the other corners the first spread kept
    auto key = [](const cv::KeyPoint& kp) {  // corners lie on whole pixels of their level
      return (static_cast<int64_t>(std::lround(kp.pt.y)) << 32) + std::lround(kp.pt.x);
    };
    for (const cv::KeyPoint& kp : kept) {
      if (kp.response >= kFavoured) {
        favoured.push_back(kp);
      } else {
        in_budget.insert(key(kp));
      }
    }
    for (const cv::KeyPoint& kp : cand) {
      if (kp.response < kFavoured) others.push_back(kp);
    }
    kept = SpreadCorners(others, target, img.cols, img.rows);
    for (cv::KeyPoint& kp : kept) {
      if (in_budget.count(key(kp)) == 0) kp.class_id = kExtraKeypoint;
    }
    kept.insert(kept.end(), favoured.begin(), favoured.end());
  }
  const float patch_size = 31.f * pyramid_.scale[level];
  for (cv::KeyPoint& kp : kept) {
    if (kp.response >= kFavoured) kp.response -= kFavoured;
    kp.octave = level;
    kp.size = patch_size;
    kp.angle = IntensityCentroidAngle(img, kp.pt);
  }
  *out = std::move(kept);
}

void OrbExtractor::ComputeDescriptors(const cv::Mat& blurred,
                                      const std::vector<cv::KeyPoint>& kps,
                                      uint8_t* out) const {
  const int step = static_cast<int>(blurred.step1());
  std::vector<int> offsets(2 * pattern_.size());
  for (size_t k = 0; k < kps.size(); ++k) {
    const cv::KeyPoint& kp = kps[k];
    int bin = static_cast<int>(std::lround(kp.angle * kAngleBins / 360.f));
    if (bin >= kAngleBins) bin -= kAngleBins;
    const auto& rotated = rotated_pattern_[bin];
    for (size_t t = 0; t < pattern_.size(); ++t) {
      offsets[2 * t] = rotated[t][1] * step + rotated[t][0];
      offsets[2 * t + 1] = rotated[t][3] * step + rotated[t][2];
    }
    const uint8_t* center = blurred.ptr<uint8_t>(cvRound(kp.pt.y)) + cvRound(kp.pt.x);
    uint8_t* d = out + k * kDescriptorBytes;
    const int* o = offsets.data();
    for (int b = 0; b < kDescriptorBytes; ++b, o += 16) {
      uint8_t byte = 0;
      for (int bit = 0; bit < 8; ++bit) {
        if (center[o[2 * bit]] < center[o[2 * bit + 1]]) byte |= static_cast<uint8_t>(1u << bit);
      }
      d[b] = byte;
    }
  }
}

void OrbExtractor::Extract(const cv::Mat& image,
                           const cv::Mat& region_mask,
                           std::vector<cv::KeyPoint>* keypoints,
                           cv::Mat* descriptors,
                           std::vector<cv::Mat>* levels_out,
                           double budget_scale) const {
  CHECK_EQ(image.type(), CV_8UC1);
  CHECK(budget_scale > 0.0 && budget_scale <= 10.0) << budget_scale;
  CHECK(region_mask.empty() ||
        (region_mask.type() == CV_8UC1 && region_mask.size() == image.size()));
  std::vector<cv::Mat> levels;
  BuildPyramid(image, &levels);
  keypoints->clear();
  std::vector<std::vector<cv::KeyPoint>> per_level(options_.num_levels);
  int total = 0;
  for (int l = 0; l < options_.num_levels; ++l) {
    cv::Mat level_mask;
    if (!region_mask.empty()) {
      if (l == 0) {
        level_mask = region_mask;
      } else {
        cv::resize(region_mask, level_mask, levels[l].size(), 0, 0, cv::INTER_NEAREST);
      }
    }
    const int target = static_cast<int>(std::lround(features_per_level_[l] * budget_scale));
    ExtractLevel(levels[l], level_mask, l, target, &per_level[l]);
    total += static_cast<int>(per_level[l].size());
  }
  descriptors->create(total, kDescriptorBytes, CV_8UC1);
  keypoints->reserve(total);
  int row = 0;
  cv::Mat blurred;
  for (int l = 0; l < options_.num_levels; ++l) {
    if (per_level[l].empty()) continue;
    cv::GaussianBlur(levels[l], blurred, cv::Size(7, 7), 2, 2, cv::BORDER_REFLECT_101);
    ComputeDescriptors(blurred, per_level[l], descriptors->ptr<uint8_t>(row));
    // Level -> level-0 pixels. cv::resize maps pixel centres, so
    // x0 = (x_l + 0.5) * W0 / W_l - 0.5 (not x_l * scale, which shifts
    // high-level keypoints by up to ~1.3 px towards the image origin).
    const float sx = static_cast<float>(image.cols) / static_cast<float>(levels[l].cols);
    const float sy = static_cast<float>(image.rows) / static_cast<float>(levels[l].rows);
    for (cv::KeyPoint kp : per_level[l]) {
      kp.pt.x = (kp.pt.x + 0.5f) * sx - 0.5f;
      kp.pt.y = (kp.pt.y + 0.5f) * sy - 0.5f;
      keypoints->push_back(kp);
    }
    row += static_cast<int>(per_level[l].size());
  }
  if (levels_out != nullptr) *levels_out = std::move(levels);
}

cv::Mat ToGray(const cv::Mat& image) {
  if (image.channels() == 1) return image;
  cv::Mat gray;
  cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  return gray;
}

}  // namespace twist::features
