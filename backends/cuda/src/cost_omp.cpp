// g++ build of the Thrust cost stage for Thrust's OpenMP system (THRUST_DEVICE_SYSTEM_OMP).
#include "cost.inl"

namespace perch2::thrust_backend {
template class Cost<OmpSystem>;
template class Cost<OmpPassesSystem>;
}  // namespace perch2::thrust_backend
