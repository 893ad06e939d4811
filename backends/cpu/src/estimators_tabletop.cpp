// TabletopEstimator<cpu::Backend>, compiled once (perch2/cpu/estimators.hpp declares it).
#include "perch2/cpu/estimators.hpp"

template class perch2::TabletopEstimator<perch2::cpu::Backend>;
