// The 6-DoF half of `perch2 estimate` (estimate.cpp parses the command line; this runs SixDofEstimator).
#pragma once

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "perch2/dataset/bop.hpp"
#include "tabletop_bop.hpp"

namespace perch2::cli {

struct SixDofOptions {
  std::string masks = "gt";  ///< "gt" (mask_visib) or a detection file (BOP/COCO JSON, RLE masks)
  bool box_full = true;      ///< ground-truth masks: the full (amodal) box, else the visible one
  std::string out, overlays;
};

/// Estimates every target instance of `images` and writes options.out; returns the exit code.
int estimate_6dof(const dataset::BopDataset& data,
                  const std::map<std::pair<int, int>, std::vector<dataset::Target>>& images,
                  const SixDofOptions& options, BackendKind backend);

}  // namespace perch2::cli
