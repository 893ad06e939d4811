#!/usr/bin/env python3
"""3-DoF tabletop estimation (x, y, yaw on the table) of a generated scene, from numpy arrays.

    python examples/python/tabletop_generated.py [--dataset DIR] [--backend cpu|thrust_omp]

Without --dataset it writes a small generated dataset with `perch2 generate --mode 3dof` (the perch2 CLI,
build/examples/perch2 or $PERCH2_CLI) and estimates its first image; prints each pose and its distance to
the ground truth.
"""

import argparse
import os
import pathlib
import subprocess
import tempfile

import numpy as np

import perch2


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", help="a BOP dataset of a tabletop scene (default: generate one)")
    ap.add_argument("--backend", default="thrust_omp")
    a = ap.parse_args()
    if a.dataset is None:
        a.dataset = tempfile.mkdtemp(prefix="perch2_3dof_")
        cli = os.environ.get("PERCH2_CLI", str(pathlib.Path(__file__).resolve().parents[2] / "build/examples/perch2"))
        subprocess.run([cli, "generate", "--mode", "3dof", "--scenes", "1", "--images-per-scene", "1",
                        "--objects", "3", "--seed", "2", "--out", a.dataset], check=True, capture_output=True)

    ds = perch2.bop.Dataset(a.dataset)
    (scene_id, im_id), targets = next(iter(ds.targets_by_image().items()))
    image = ds.image(scene_id, im_id)
    depth_m, rgb, K = image.depth_m, image.rgb, image.K  # numpy: H x W float32, H x W x 3 uint8, 3 x 3

    obj_ids = sorted({t.obj_id for t in targets})
    meshes = [ds.load_model(i) for i in obj_ids]  # perch2.Mesh in metres (BOP models are in mm)
    estimator = perch2.TabletopEstimator(meshes, backend=a.backend, variant="perch2-c")
    objects = {obj_ids.index(t.obj_id): t.inst_count for t in targets}  # {model index or mesh name: count}
    result = estimator.estimate(depth_m, rgb, K, objects, T_cam_world=image.info.T_cam_world)

    gt = image.info.gt
    for p in result.poses:
        obj_id = obj_ids[p.model]
        d = min(np.linalg.norm(p.T_cam_obj[:3, 3] - g.T_cam_obj[:3, 3]) for g in gt if g.obj_id == obj_id)
        print(f"obj {obj_id}: x {p.x_m:+.3f} m, y {p.y_m:+.3f} m, yaw {np.degrees(p.yaw_rad):6.1f} deg, "
              f"cost {p.cost.total:.3f}, {1000 * d:.1f} mm from the ground truth")
    t = result.timings
    print(f"{result.hypotheses_kept} hypotheses; {t.total:.2f} s (render {t.render:.2f}, refine {t.refine:.2f}, "
          f"cost {t.cost:.2f})")


if __name__ == "__main__":
    main()
