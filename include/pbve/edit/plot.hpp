#pragma once
/// @file
/// Plots of reports, like the paper's Figures 7 and 8: violation % per frame, and control vs
/// physical force per frame (constrained vs unconstrained when two reports are given).

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "pbve/edit/report.hpp"

namespace pbve {

/// Draws one figure (8-bit BGR, `width` x `height`) with two panels: top, violation_pct per
/// frame for each report; bottom, control force and physical force per frame for each report
/// (log scale). `labels` name the reports in the legend (defaults: "run 1", "run 2", ...).
/// Throws InputError for a size outside 400x300 .. 16384x16384.
cv::Mat plot_reports(const std::vector<Report>& reports, const std::vector<std::string>& labels,
                     int width = 1200, int height = 800);

/// Tick values of a linear axis over [lo, hi]: the multiples of a round step (1, 2 or 5 times a
/// power of ten, at least `min_step`) that lie in it, at most `max_intervals` steps apart
/// end to end. Empty when hi < lo, or when hi - lo or min_step is not finite.
std::vector<double> axis_ticks(double lo, double hi, int max_intervals, double min_step = 0.0);

/// The text of a value axis's tick at v: up to four significant digits ("0.25", "40", "1000"),
/// scientific below 0.01 and from 10^4 on ("1e-03", "1e+04"); "0" for 0. (Frame numbers are
/// written as whole numbers.)
std::string tick_label(double v);

}  // namespace pbve
