// The Thrust registration built by nvcc for CUDA devices (perch2::cuda).
#include "registration.inl"

static_assert(THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_CUDA,
              "registration.cu must build for Thrust's CUDA system");
template class perch2::thrust_backend::Registration<perch2::thrust_backend::CudaSystem>;
