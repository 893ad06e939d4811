#!/usr/bin/env python3
"""What calling perch2 from Python costs: converting a 640 x 480 frame from numpy, and the share of a 6-DoF
estimate spent outside the C++ estimator (argument conversion, GIL release, result conversion).

    PYTHONPATH=build/python .venv/bin/python bench/bench_python.py [--dataset BOP_DIR] [--runs 7]

Without --dataset it generates a 6-DoF scene with the perch2 CLI (build/examples/perch2 generate). The
estimator's own wall time is SixDofResult.timings.total (measured in C++); the Python call's overhead is the
call's wall time minus that. Medians of --runs runs; on a loaded machine compare the shares, not seconds.
"""

import argparse
import os
import pathlib
import statistics
import subprocess
import tempfile
import time

import numpy as np

import perch2


def median_seconds(f, runs):
    out = []
    for _ in range(runs):
        t0 = time.perf_counter()
        f()
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", help="a BOP dataset (default: a generated 6-DoF scene)")
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--backend", default="thrust_omp")
    a = ap.parse_args()
    root = pathlib.Path(__file__).resolve().parents[1]
    if a.dataset is None:
        tmp = tempfile.mkdtemp(prefix="bench_python_")
        cli = os.environ.get("PERCH2_CLI", str(root / "build" / "examples" / "perch2"))
        subprocess.run([cli, "generate", "--mode", "6dof", "--scenes", "1", "--images-per-scene", "1", "--objects",
                        "4", "--seed", "3", "--out", tmp], check=True, capture_output=True)
        a.dataset = tmp
    ds = perch2.bop.Dataset(a.dataset)
    (scene_id, im_id), _ = next(iter(ds.targets_by_image().items()))
    image = ds.image(scene_id, im_id)
    ids = sorted({g.obj_id for g in image.info.gt})
    instances = [(ids.index(g.obj_id), m.astype(bool), None) for g, m in zip(image.info.gt, image.masks_visib)]
    depth, rgb, K = np.ascontiguousarray(image.depth_m), np.ascontiguousarray(image.rgb), image.K
    h, w = depth.shape
    print(f"perch2 {perch2.__version__}, backend {a.backend}, {w} x {h}, {len(instances)} instances, "
          f"{a.runs} runs (medians), load average {os.getloadavg()[0]:.1f}")

    print("\nconverting numpy inputs (one copy into perch2's images):")
    depth16 = (depth * 1000).astype(np.uint16)
    rows = [
        ("RgbdFrame(depth float32, rgb uint8, K)", lambda: perch2.RgbdFrame(depth, rgb, K)),
        ("RgbdFrame(depth uint16 + scale, rgb, K)", lambda: perch2.RgbdFrame(depth16, rgb, K, depth_scale_m=0.001)),
        ("SixDofInstance(model, bool mask)", lambda: perch2.SixDofInstance(0, instances[0][1])),
    ]
    for name, f in rows:
        f()
        s = median_seconds(f, 50)
        print(f"  {name:42s} {1000 * s:7.3f} ms")

    est = perch2.SixDofEstimator([perch2.sixdof_model(ds.load_model(i), ds.model_info(i)) for i in ids],
                                 backend=a.backend)
    frame = perch2.RgbdFrame(depth, rgb, K)
    est.estimate(frame, instances)  # warm-up (workspaces, page faults)
    print("\n6-DoF estimate from Python (wall) vs the C++ estimator's own timings.total:")
    for name, call in (("estimate(frame, instances)", lambda: est.estimate(frame, instances)),
                       ("estimate(depth, rgb, K, instances)", lambda: est.estimate(depth, rgb, K, instances))):
        wall, inner = [], []
        for _ in range(a.runs):
            t0 = time.perf_counter()
            r = call()
            wall.append(time.perf_counter() - t0)
            inner.append(r.timings.total)
        over = [w_ - i_ for w_, i_ in zip(wall, inner)]
        share = statistics.median([o / i_ for o, i_ in zip(over, inner)])
        print(f"  {name:36s} wall {statistics.median(wall):7.3f} s, C++ {statistics.median(inner):7.3f} s, "
              f"overhead {1000 * statistics.median(over):7.3f} ms = {100 * share:.3f} %")


if __name__ == "__main__":
    main()
