"""perch2.distributed on this machine: throughput of one worker with 2 OpenMP threads against two workers with one
thread each, and what Ray costs per image, on a generated 6-DoF dataset (a local Ray instance of 2 CPUs).

    PYTHONPATH=build/python python bench/bench_distributed.py [--images 12] [--runs 3] [--cli build/examples/perch2]

Per configuration (median of --runs runs): images/s over the whole run (driver wall clock, Ray's start-up
excluded: the cluster is started once), the estimator's own seconds per image, a worker's start-up (actor
created, dataset opened, models loaded: a fixed cost per run), the per-image overhead while the workers are
busy (first image started to last returned, driver's clock, minus the estimates: decoding, Python, pickling,
Ray's calls and scheduling gaps) as a share of the estimate time, and the end-to-end overhead
(workers x wall - sum of estimate seconds) / sum of estimate seconds: everything that is not estimation,
start-up and the last images' tail (one worker idle while another finishes) included, which a long run
amortises. Peak resident memory per worker process.
"""

import argparse
import os
import pathlib
import statistics
import subprocess
import sys
import tempfile
import time

import ray

import perch2.distributed as pd


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--images", type=int, default=12, help="generated 6-DoF images (scenes of 2 images)")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--cli", default=str(pathlib.Path(__file__).resolve().parents[1] / "build/examples/perch2"))
    p.add_argument("--seed", type=int, default=2020)
    a = p.parse_args()
    scratch = pathlib.Path(tempfile.mkdtemp(prefix="perch2_bench_distributed_"))
    dataset = scratch / "dataset"
    subprocess.run([a.cli, "generate", "--mode", "6dof", "--scenes", str((a.images + 1) // 2), "--images-per-scene",
                    "2", "--objects", "4-6", "--seed", str(a.seed), "--out", str(dataset)], check=True,
                   stdout=subprocess.DEVNULL)
    t = time.perf_counter()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    print(f"bench_distributed: {a.images} generated 6-DoF images (seed {a.seed}), local Ray {ray.__version__} "
          f"with 2 CPUs (started in {time.perf_counter() - t:.1f} s), {a.runs} runs per row, medians")
    print("| workers x threads | images/s | estimate s/image | start-up s | overhead while busy "
          "| end-to-end overhead | peak MiB/worker |")
    print("|---|---|---|---|---|---|---|")
    config = pd.RunConfig(mode="6dof")
    for workers, threads in ((1, 2), (2, 1)):
        rates, estimate, startup, busy, overall, peak = [], [], [], [], [], []
        for r in range(a.runs):
            out = scratch / f"results_{workers}x{threads}_{r}.csv"
            s = pd.run(str(dataset), str(out), config, workers=workers, threads_per_worker=threads, progress=None)
            assert s.done == s.total and not s.skipped and not s.failed, s
            rates.append(s.done / s.wall_seconds)
            estimate.append(s.estimate_seconds / s.done)
            startup.append(s.startup_seconds)
            busy.append((s.busy_seconds - s.estimate_seconds) / s.estimate_seconds)
            overall.append((workers * s.wall_seconds - s.estimate_seconds) / s.estimate_seconds)
            peak.append(max(s.peak_rss_mib.values()))
        m = statistics.median
        print(f"| {workers} x {threads} | {m(rates):.2f} | {m(estimate):.2f} | {m(startup):.1f} "
              f"| {100 * m(busy):.1f}% | {100 * m(overall):.1f}% | {m(peak):.0f} |")
        sys.stdout.flush()
    ray.shutdown()


if __name__ == "__main__":
    os.environ.setdefault("OMP_WAIT_POLICY", "passive")
    main()
