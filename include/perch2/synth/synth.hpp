// Synthetic BOP datasets for perch2 (link perch2::synth): models, scenes, sensor rendering, detections.
#pragma once

#include "perch2/synth/dataset.hpp"
#include "perch2/synth/detections.hpp"
#include "perch2/synth/models.hpp"
#include "perch2/synth/preview.hpp"
#include "perch2/synth/scene.hpp"
#include "perch2/synth/sensor.hpp"
#include "perch2/synth/video.hpp"
