// The Thrust renderer built by g++ for Thrust's OpenMP device system (perch2::thrust_omp).
#include "render.inl"

static_assert(THRUST_DEVICE_SYSTEM == THRUST_DEVICE_SYSTEM_OMP,
              "render_omp.cpp must build for Thrust's OMP system");
template class perch2::thrust_backend::Renderer<perch2::thrust_backend::OmpSystem>;
template class perch2::thrust_backend::Renderer<perch2::thrust_backend::OmpPassesSystem>;
