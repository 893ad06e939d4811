// perch2._perch2: the C++ library's Python bindings (the perch2 package re-exports them).
#include "common.hpp"

NB_MODULE(_perch2, m) {
  m.doc() = "perch2: training-free object pose estimation by parallel render-and-compare search (PERCH 2.0).";
  m.attr("__version__") = PERCH2_VERSION;
  perch2_py::bind_core(m);
  perch2_py::bind_stages(m);
  perch2_py::bind_dataset(m);
  perch2_py::bind_estimators(m);
  perch2_py::bind_runner(m);
  perch2_py::bind_eval(m);
  perch2_py::bind_track(m);
}
