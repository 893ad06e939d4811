"""perch2: training-free object pose estimation by parallel render-and-compare search (PERCH 2.0).

numpy in, numpy out; metres, radians; poses are 4 x 4 float32 arrays T_cam_obj (object -> camera).

    import perch2
    est = perch2.SixDofEstimator([perch2.load_mesh("cat.ply", scale=0.001)], backend="thrust_omp")
    result = est.estimate(depth_m, rgb, K, [(0, mask, None)])   # mask: H x W bool from any detector
    result.poses[0].T_cam_obj

Estimators: TabletopEstimator (3-DoF on a table), SixDofEstimator (6-DoF from masks). Stages: Renderer,
KnnIndex, Registration, Cost. Data: perch2.bop (BOP datasets, detections, results CSV), perch2.eval.
Bad input raises perch2.InvalidInput (a ValueError) or perch2.FileError (an OSError) naming the input.
"""

from . import _perch2
from ._perch2 import *  # noqa: F401,F403  (the bindings: same names as the C++ API)
from ._perch2 import __version__, FileError, InvalidInput  # noqa: F401

from . import bop, eval  # noqa: E402,F401  (pure-Python helpers over the bindings)

__all__ = [name for name in dir(_perch2) if not name.startswith("_")] + ["bop", "eval", "__version__"]
