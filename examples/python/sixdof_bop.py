#!/usr/bin/env python3
"""6-DoF estimation over a BOP dataset with a detection file, writing a BOP results CSV (and scoring it).

    python examples/python/sixdof_bop.py --dataset DIR --detections DETS.json --out results.csv [--eval]

The detection file is the BOP/COCO format (masks as RLE, counts as a list or a string). Every target
instance of the dataset's targets file is estimated from its detection's mask and box, exactly as
`perch2 estimate --mode 6dof --masks DETS.json` does (the same rows, but for the time column).
"""

import argparse
import sys

import perch2


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--detections", required=True, help="BOP/COCO detection file, or 'gt' for the GT masks")
    ap.add_argument("--out", required=True)
    ap.add_argument("--backend", default="thrust_omp")
    ap.add_argument("--eval", action="store_true", help="score the results (perch2.eval, no VSD)")
    a = ap.parse_args()

    def progress(done, total):
        print(f"\r  {done}/{total} images", end="\n" if done == total else "", file=sys.stderr, flush=True)

    rows = perch2.bop.estimate_6dof(a.dataset, masks=a.detections, backend=a.backend, progress=progress)
    perch2.bop.save_results_csv(a.out, rows)
    print(f"{len(rows)} poses -> {a.out}")
    if a.eval:
        report = perch2.eval.evaluate(a.dataset, a.out, vsd=False)["overall"]
        print(f"ADD(-S) AUC {100 * report['auc_add_or_adds']:.1f}, ADD-S AUC {100 * report['auc_adds']:.1f}, "
              f"ADD-S < 2 cm {100 * report['adds_below_2cm']:.1f} %, AR (MSSD, MSPD) {100 * report['ar']:.1f}")


if __name__ == "__main__":
    main()
