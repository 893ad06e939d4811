// SixDofEstimator and TabletopEstimator over cuda::Backend, compiled once into perch2::cuda
// (perch2/cuda/estimators.hpp declares them). Host code: the estimators call the backend's stages, whose
// device work lives in the .cu files.
#include "perch2/cuda/estimators.hpp"

template class perch2::SixDofEstimator<perch2::cuda::Backend>;
template class perch2::TabletopEstimator<perch2::cuda::Backend>;
