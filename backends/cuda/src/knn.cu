// nvcc build of the Thrust nearest-neighbour search (THRUST_DEVICE_SYSTEM_CUDA).
#include "knn.inl"

namespace perch2::thrust_backend {
template class KnnIndex<CudaSystem>;
}
