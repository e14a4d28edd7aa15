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
cv::Mat plot_reports(const std::vector<Report>& reports, const std::vector<std::string>& labels,
                     int width = 1200, int height = 800);

}  // namespace pbve
