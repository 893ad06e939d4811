// The Thrust registration built by g++ for Thrust's OpenMP device system (perch2::thrust_omp).
#include "registration.inl"

static_assert(THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_OMP,
              "registration_omp.cpp must build for Thrust's OMP system");
template class perch2::thrust_backend::Registration<perch2::thrust_backend::OmpSystem>;
template class perch2::thrust_backend::Registration<perch2::thrust_backend::OmpPassesSystem>;
