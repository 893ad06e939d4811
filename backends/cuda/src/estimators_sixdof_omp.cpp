// SixDofEstimator<thrust_omp::Backend>, compiled once (perch2/cuda/estimators.hpp declares it).
#include "perch2/cuda/estimators.hpp"

template class perch2::SixDofEstimator<perch2::thrust_omp::Backend>;
