// nvcc build of the Thrust cost stage (THRUST_DEVICE_SYSTEM_CUDA).
#include "cost.inl"

namespace perch2::thrust_backend {
template class Cost<CudaSystem>;
}
