// g++ build of the Thrust nearest-neighbour search for Thrust's OpenMP system (THRUST_DEVICE_SYSTEM_OMP).
#include "knn.inl"

namespace perch2::thrust_backend {
template class KnnIndex<OmpSystem>;
template class KnnIndex<OmpPassesSystem>;  // the registration in passes (OmpPassesSystem) uses it
}  // namespace perch2::thrust_backend
