// The Thrust renderer built by nvcc for CUDA devices (perch2::cuda).
#include "render.inl"

static_assert(THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_CUDA,
              "render.cu must build for Thrust's CUDA system");
template class perch2::thrust_backend::Renderer<perch2::thrust_backend::CudaSystem>;
