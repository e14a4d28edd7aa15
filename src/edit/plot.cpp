#include "pbve/edit/plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <opencv2/imgproc.hpp>

#include "pbve/core/error.hpp"

namespace pbve {

namespace {

const cv::Scalar kInk(40, 40, 40);
const cv::Scalar kGrid(225, 225, 225);
// Colour per report (BGR): blue-ish, orange-ish, green, purple.
const cv::Scalar kColours[] = {{180, 110, 30}, {30, 120, 230}, {60, 160, 60}, {160, 60, 150}};

struct Panel {
  cv::Rect box;
  double x0, x1, y0, y1;
  bool log_y;
  cv::Point map(double x, double y) const {
    const double fx = (x - x0) / std::max(x1 - x0, 1e-12);
    double fy;
    if (log_y) {
      const double ly = std::log10(std::max(y, std::pow(10.0, y0)));
      fy = (ly - y0) / std::max(y1 - y0, 1e-12);
    } else {
      fy = (y - y0) / std::max(y1 - y0, 1e-12);
    }
    fy = std::clamp(fy, 0.0, 1.0);
    return {box.x + static_cast<int>(std::lround(fx * box.width)),
            box.y + box.height - static_cast<int>(std::lround(fy * box.height))};
  }
};

/// The round step (1, 2 or 5 times a power of ten, at least min_step) that splits `range` into
/// at most `max_intervals` intervals.
double round_step(double range, int max_intervals, double min_step) {
  const double raw = std::max(range / std::max(max_intervals, 1), 1e-300);
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  double step = 10.0 * mag;
  for (const double m : {1.0, 2.0, 5.0})
    if (m * mag >= raw * (1.0 - 1e-9)) {
      step = m * mag;
      break;
    }
  return std::max(step, min_step);
}

void axes(cv::Mat& img, const Panel& p, const std::string& title, const std::string& ylabel) {
  const auto y_tick = [&](double t, const std::string& label) {
    const int y = p.box.y + p.box.height - static_cast<int>(std::lround(t * p.box.height));
    cv::line(img, {p.box.x, y}, {p.box.x + p.box.width, y}, kGrid, 1);
    cv::putText(img, label, {p.box.x - 70, y + 5}, cv::FONT_HERSHEY_SIMPLEX, 0.45, kInk, 1,
                cv::LINE_AA);
  };
  if (p.log_y) {
    // Whole decades, every one up to 6 of them.
    const double every = std::max(1.0, std::ceil((p.y1 - p.y0) / 6.0));
    for (int k = 0; k <= 7; ++k) {
      const double d = p.y0 + k * every;
      if (d > p.y1 + 1e-9) break;
      y_tick((d - p.y0) / (p.y1 - p.y0), tick_label(std::pow(10.0, d)));
    }
  } else {
    for (const double v : axis_ticks(p.y0, p.y1, 6))
      y_tick((v - p.y0) / (p.y1 - p.y0), tick_label(v));
  }
  // Frame numbers at whole frames (a short report got 0 0 0 1 1 1 once).
  for (const double frame : axis_ticks(p.x0, p.x1, 6, 1.0))
    cv::putText(img, std::to_string(std::llround(frame)),
                {p.map(frame, 0.0).x - 10, p.box.y + p.box.height + 20}, cv::FONT_HERSHEY_SIMPLEX,
                0.45, kInk, 1, cv::LINE_AA);
  cv::rectangle(img, p.box, kInk, 1);
  cv::putText(img, title, {p.box.x, p.box.y - 12}, cv::FONT_HERSHEY_SIMPLEX, 0.6, kInk, 1,
              cv::LINE_AA);
  cv::putText(img, ylabel,
              {p.box.x + p.box.width - 8 * static_cast<int>(ylabel.size()) - 10, p.box.y - 12},
              cv::FONT_HERSHEY_SIMPLEX, 0.45, kInk, 1, cv::LINE_AA);
}

void polyline(cv::Mat& img, const Panel& p, const std::vector<FrameRecord>& frames,
              double FrameRecord::*field, const cv::Scalar& colour, bool dashed) {
  // A NaN value (a frame whose figure could not be computed) leaves a gap in the line.
  std::vector<cv::Point> pts;
  std::vector<char> known;
  for (const FrameRecord& f : frames) {
    known.push_back(!std::isnan(f.*field));
    pts.push_back(known.back() ? p.map(f.index, f.*field) : cv::Point());
  }
  for (size_t i = 1; i < pts.size(); ++i) {
    if ((dashed && (i / 3) % 2) || !known[i - 1] || !known[i]) continue;
    cv::line(img, pts[i - 1], pts[i], colour, 2, cv::LINE_AA);
  }
}

}  // namespace

std::string tick_label(double v) {
  char buf[32];
  if (v != 0.0 && (std::abs(v) >= 1e4 || std::abs(v) < 1e-2))
    std::snprintf(buf, sizeof buf, "%.0e", v);
  else
    std::snprintf(buf, sizeof buf, "%.4g", v);
  return buf;
}

std::vector<double> axis_ticks(double lo, double hi, int max_intervals, double min_step) {
  std::vector<double> ticks;
  if (!(hi >= lo) || !std::isfinite(hi - lo) || !std::isfinite(min_step)) return ticks;
  if (hi == lo) return {lo};
  const double step = round_step(hi - lo, max_intervals, min_step);
  const double eps = 1e-9 * step;
  const double k0 = std::ceil(lo / step - 1e-9);
  // At most max_intervals + 1 ticks by construction; the bound also stops a step too small to
  // advance k (a range far from zero).
  const long long last = static_cast<long long>(std::max(max_intervals, 1)) + 1;
  for (long long i = 0; i <= last; ++i) {
    const double v = (k0 + i) * step;
    if (v > hi + eps) break;
    ticks.push_back(v == 0.0 ? 0.0 : v);  // no -0
  }
  return ticks;
}

cv::Mat plot_reports(const std::vector<Report>& reports, const std::vector<std::string>& labels,
                     int width, int height) {
  // The margins, titles and two panels need this much room.
  if (width < 400 || height < 300 || width > 16384 || height > 16384)
    throw InputError("plot_reports: the figure must be 400x300 to 16384x16384 pixels, got " +
                     std::to_string(width) + "x" + std::to_string(height));
  cv::Mat img(height, width, CV_8UC3, cv::Scalar(255, 255, 255));
  double x0 = 1e300, x1 = -1e300, vmax = 0.0, fmin = 1e300, fmax = 0.0;
  for (const Report& r : reports)
    for (const FrameRecord& f : r.frames) {
      x0 = std::min(x0, static_cast<double>(f.index));
      x1 = std::max(x1, static_cast<double>(f.index));
      // The axes from the finite values (an infinite force is drawn at the top).
      if (std::isfinite(f.violation_pct)) vmax = std::max(vmax, f.violation_pct);
      for (double v : {f.control_force, f.physical_force}) {
        if (!std::isfinite(v)) continue;
        if (v > 0) fmin = std::min(fmin, v);
        fmax = std::max(fmax, v);
      }
    }
  if (x0 > x1) x0 = 0, x1 = 1;
  if (x1 == x0) x1 = x0 + 1;
  if (fmax <= 0) fmin = 1e-3, fmax = 1.0;
  const int left = 90, right = 30, top = 50, gap = 80, bottom = 70;
  const int ph = (height - top - gap - bottom) / 2;
  // The violation axis ends at the first round tick at or above the highest value.
  const double vtop = std::max(1.0, vmax), vstep = round_step(vtop, 6, 0.0);
  Panel viol{{left, top, width - left - right, ph}, x0,   x1, 0.0,
             vstep * std::ceil(vtop / vstep),       false};
  Panel force{
      {left, top + ph + gap, width - left - right, ph}, x0,  x1, std::floor(std::log10(fmin)),
      std::ceil(std::log10(fmax) + std::log10(1.01)),   true};
  if (force.y1 <= force.y0) force.y1 = force.y0 + 1;
  axes(img, viol, "Area of violating triangles (% of visible object area) per frame", "%");
  axes(img, force, "Control force (solid) and physical force (dashed) per frame", "N (log)");
  cv::putText(img, "frame", {width / 2 - 20, height - 15}, cv::FONT_HERSHEY_SIMPLEX, 0.5, kInk, 1,
              cv::LINE_AA);
  for (size_t i = 0; i < reports.size(); ++i) {
    const cv::Scalar c = kColours[i % 4];
    polyline(img, viol, reports[i].frames, &FrameRecord::violation_pct, c, false);
    polyline(img, force, reports[i].frames, &FrameRecord::control_force, c, false);
    polyline(img, force, reports[i].frames, &FrameRecord::physical_force, c, true);
    const std::string label = i < labels.size() ? labels[i] : "run " + std::to_string(i + 1);
    const int ly = top + 20 + 22 * static_cast<int>(i);
    cv::line(img, {width - right - 260, ly - 5}, {width - right - 230, ly - 5}, c, 3, cv::LINE_AA);
    cv::putText(img, label, {width - right - 222, ly}, cv::FONT_HERSHEY_SIMPLEX, 0.5, kInk, 1,
                cv::LINE_AA);
  }
  return img;
}

}  // namespace pbve
