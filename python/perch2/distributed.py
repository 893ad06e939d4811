"""A BOP dataset run sharded over a Ray cluster: one actor per worker holds a perch2 estimator (models loaded
once, workspaces warm), images are tasks the actors pull, and the driver writes the one results CSV.

    python -m perch2.distributed estimate --dataset DIR --out results.csv --address auto --workers 4 \\
        --threads-per-worker 2 --mode 6dof --masks gt

    import perch2.distributed as pd
    summary = pd.run("DIR", "results.csv", pd.RunConfig(mode="6dof"), workers=2)

What an image run does -- the estimate, which bad images are skipped and why -- is the C++ BopRunner's, as in
`perch2 estimate`; the driver's results file is the same ResultsWriter's (each image's rows appended and
flushed when the image is done, recorded in RESULTS.csv.done), so the CLI and this driver resume each
other's files and write the same rows.

- Scheduling: each actor has at most `queue_per_worker` images in flight and gets the next one when it
  returns one, so a slow or busy worker gets fewer.
- Data: workers read the dataset from `dataset` (a path every node sees: a shared folder or an object-store
  mount), or, with `ship_images=True`, from bytes the driver sends: the dataset's small files (models, JSON,
  the detection file) once per run through Ray's object store, and each image's files with its task.
- Faults: an actor whose process dies (killed, out of memory) is restarted by Ray; the image it was running
  goes back to the queue, and an image that was running on `max_attempts` dead workers is reported as failed
  instead of being retried forever. Images queued behind it are re-sent without counting an attempt. No image
  is written twice (the writer refuses a second write) or lost (an unwritten image is not in the .done file,
  so `resume=True` runs it again).
- Resources: each actor asks Ray for `threads_per_worker` CPUs (its OpenMP threads, set through
  OMP_NUM_THREADS in its environment) and `gpus_per_worker` GPUs (the cuda backend), so Ray packs workers
  onto machines correctly.
"""

from __future__ import annotations

import argparse
import atexit
import dataclasses
import os
import pathlib
import resource
import shutil
import signal
import sys
import tempfile
import time
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import perch2

ImageKey = Tuple[int, int]

try:  # Ray is an optional dependency: `pip install perch2[ray]`
    import ray
except ImportError:  # pragma: no cover - exercised only without Ray
    ray = None


def _need_ray():
    if ray is None:
        raise ImportError("perch2.distributed needs Ray: pip install 'ray[default]' (or perch2[ray])")


# ---- what each image is estimated with ------------------------------------------------------------------


@dataclasses.dataclass
class RunConfig:
    """The options of `perch2 estimate` (same names and defaults); see `perch2 estimate --help`."""

    mode: str = "3dof"  #: "3dof" | "6dof"
    variant: str = "perch2c"  #: 3-DoF search variant
    backend: str = "thrust_omp"  #: "cpu" | "thrust_omp" | "cuda"
    masks: str = "gt"  #: 6-DoF: "gt" (mask_visib) or a detection file (a path every worker sees, or shipped)
    box: str = "full"  #: 6-DoF with gt masks: "full" | "visible"
    split: str = "test"
    targets: str = ""  #: targets file under the dataset root ("" = test_targets_bop19.json, else _bop24)
    scenes: Optional[Tuple[int, int]] = None  #: only scenes A..B (inclusive)

    def run_options(self) -> "perch2.RunOptions":
        return perch2.RunOptions(mode=self.mode, backend=self.backend, variant=self.variant, masks=self.masks,
                                 box=self.box)

    def open_dataset(self, root: str) -> "perch2.BopDataset":
        # The ground truth only when the masks come from it: an estimator never reads it otherwise.
        return perch2.BopDataset(root, split=self.split, targets_file=self.targets,
                                 ground_truth=self.mode == "6dof" and self.masks == "gt")

    def scene_range(self) -> Tuple[int, int]:
        return self.scenes if self.scenes is not None else (0, 1 << 30)


# ---- the dataset without its images, for workers that do not see the path ----------------------------


_IMAGE_FOLDERS = {"rgb", "depth", "mask", "mask_visib", "gray", "depth_noisy"}


def _pack_dataset(root: str, config: RunConfig) -> Dict[str, bytes]:
    """Every file of the dataset but its image folders (models, JSON, targets), relative path -> bytes, plus
    the detection file under "__masks__" when the masks come from one."""
    root_path = pathlib.Path(root)
    out = {}
    for path in root_path.rglob("*"):
        rel = path.relative_to(root_path)
        if path.is_file() and not (set(rel.parts[:-1]) & _IMAGE_FOLDERS):
            out[str(rel)] = path.read_bytes()
    if config.masks not in ("gt", "none"):
        out["__masks__"] = pathlib.Path(config.masks).read_bytes()
    return out


def _unpack_dataset(files: Dict[str, bytes], config: RunConfig) -> Tuple[str, RunConfig]:
    root = pathlib.Path(tempfile.mkdtemp(prefix="perch2_dataset_"))
    atexit.register(shutil.rmtree, root, ignore_errors=True)  # the worker's copy goes with its process
    for rel, data in files.items():
        if rel == "__masks__":
            continue
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_bytes(data)
    if "__masks__" in files:
        masks = root / "__detections__.json"
        masks.write_bytes(files["__masks__"])
        config = dataclasses.replace(config, masks=str(masks))
    return str(root), config


# ---- the worker ------------------------------------------------------------------------------------------


class Worker:
    """One estimator per process (a Ray actor). Never raises for a bad image: reports it in the result."""

    def __init__(self, index: int, dataset, config: RunConfig, dies_on: Optional[ImageKey] = None):
        self.dies_on = dies_on  # fault injection for the tests: this process SIGKILLs itself on that image
        if isinstance(dataset, dict):  # shipped: the dataset's small files
            dataset, config = _unpack_dataset(dataset, config)
        self.index = index
        self.data = config.open_dataset(dataset)
        self.runner = perch2.BopRunner(self.data, config.run_options())

    def pid(self) -> int:
        return os.getpid()

    def estimate(self, key: ImageKey, files=None) -> dict:
        start = time.perf_counter()
        out = dict(key=key, worker=self.index, pid=os.getpid())
        if self.dies_on is not None and tuple(key) == tuple(self.dies_on):
            os.kill(os.getpid(), signal.SIGKILL)
        try:
            if files is None:
                r = self.runner.estimate(*key)
            else:
                r = self.runner.estimate(key[0], key[1], files)
        except (perch2.ImageError, perch2.FileError, perch2.InvalidInput) as e:
            out["error"] = str(e)
        else:
            out.update(rows=list(r.rows), stages=list(r.stages), seconds=r.seconds,
                       requested=r.requested, missing=r.missing, unusable=r.unusable)
        out["wall"] = time.perf_counter() - start
        out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
        return out


# ---- the driver ------------------------------------------------------------------------------------------


@dataclasses.dataclass
class RunSummary:
    total: int = 0  #: images of the run (those already complete on resume included)
    resumed: int = 0  #: complete in the results file before this run
    done: int = 0  #: written by this run
    skipped: Dict[ImageKey, str] = dataclasses.field(default_factory=dict)  #: bad images: why
    failed: Dict[ImageKey, str] = dataclasses.field(default_factory=dict)  #: killed max_attempts workers
    per_worker: Dict[int, int] = dataclasses.field(default_factory=dict)  #: images done per worker
    peak_rss_mib: Dict[int, float] = dataclasses.field(default_factory=dict)  #: per worker process, MiB
    stages: Dict[str, float] = dataclasses.field(default_factory=dict)  #: seconds summed over workers
    worker_seconds: float = 0  #: sum of the workers' wall time per image (estimate + decode + Ray's call)
    estimate_seconds: float = 0  #: sum of the estimators' own time per image
    wall_seconds: float = 0  #: the driver's wall time from the first task to the last write
    startup_seconds: float = 0  #: mean over workers: run start to the worker's first image (Ray, model loading)
    busy_seconds: float = 0  #: sum over workers: first image started to last image returned (driver's clock)
    restarts: int = 0  #: worker processes that died and were restarted
    interrupted: bool = False

    @property
    def exit_code(self) -> int:
        """As `perch2 estimate`: 0; 3 if an image was skipped or failed; 130 if interrupted."""
        return 130 if self.interrupted else 3 if (self.skipped or self.failed) else 0


class _Progress:
    def __init__(self, out, total, already):
        self.out, self.total, self.already, self.start = out, total, already, time.perf_counter()

    def show(self, summary: RunSummary):
        if self.out is None:
            return
        n = summary.done + len(summary.skipped) + len(summary.failed)
        elapsed = time.perf_counter() - self.start
        rate = n / elapsed if elapsed > 0 else 0.0
        left = self.total - self.already - n
        eta = left / rate if rate > 0 else float("inf")
        workers = " ".join(f"w{k}:{v}" for k, v in sorted(summary.per_worker.items()))
        self.out.write(f"perch2.distributed: {self.already + n}/{self.total} images, {rate:.2f} images/s, "
                       f"ETA {eta:.0f} s [{workers}]\n")
        self.out.flush()


def _connect(address: Optional[str], num_cpus: int):
    if ray.is_initialized():
        return
    if address in (None, "", "local"):  # a cluster of this machine only
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
    else:
        ray.init(address=address, log_to_driver=False)


def run(dataset: str, out: str, config: RunConfig = RunConfig(), *, workers: int = 2, threads_per_worker: int = 1,
        gpus_per_worker: float = 0, address: Optional[str] = None, resume: bool = False, strict: bool = False,
        ship_images: bool = False, max_attempts: int = 3, queue_per_worker: int = 2, progress=sys.stderr,
        on_result: Optional[Callable[[dict, RunSummary, list], None]] = None,
        _worker_dies_on: Optional[ImageKey] = None) -> RunSummary:
    """Estimates every target image of `dataset` on `workers` Ray actors and writes `out` (BOP CSV).

    `address`: None or "local" starts Ray on this machine (workers x threads_per_worker CPUs); "auto" or
    "HOST:PORT" joins a running cluster. `on_result(result, summary, actors)` is called after each returned
    image (tests use it to kill a worker mid-run; `_worker_dies_on` makes every worker process that starts
    that image kill itself, to test the bounded retries). Returns the RunSummary; see RunSummary.exit_code."""
    _need_ray()
    if workers < 1 or threads_per_worker < 1 or max_attempts < 1 or queue_per_worker < 1:
        raise perch2.InvalidInput("workers/threads_per_worker/max_attempts/queue_per_worker", "must be >= 1")
    if gpus_per_worker < 0:
        raise perch2.InvalidInput("gpus_per_worker", "must be >= 0")
    if config.backend == "cuda" and gpus_per_worker <= 0:
        raise perch2.InvalidInput("gpus_per_worker", "the cuda backend needs a GPU per worker (e.g. 1)")
    data = config.open_dataset(dataset)  # dataset-level problems fail here, at once
    images = perch2.run_images(data, *config.scene_range())
    writer = perch2.ResultsWriter(out, resume=resume)  # unwritable output fails here too
    summary = RunSummary(total=len(images))
    queue = [k for k in images if not writer.is_done(*k)]
    summary.resumed = len(images) - len(queue)
    if not queue:
        return summary

    _connect(address, workers * threads_per_worker)
    env = {"OMP_NUM_THREADS": str(threads_per_worker),
           "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY", "passive")}
    actor_class = ray.remote(Worker).options(num_cpus=threads_per_worker, num_gpus=gpus_per_worker,
                                             max_restarts=-1, max_task_retries=0,
                                             runtime_env={"env_vars": env})
    source = ray.put(_pack_dataset(dataset, config)) if ship_images else str(pathlib.Path(dataset).resolve())
    actors = [actor_class.remote(i, source, config, _worker_dies_on) for i in range(min(workers, len(queue)))]

    queue.reverse()  # pop() from the end: images in dataset order
    attempts: Dict[ImageKey, int] = {}
    in_flight: Dict["ray.ObjectRef", Tuple[ImageKey, int]] = {}  # ref -> (image, actor)
    sent: Dict[int, List["ray.ObjectRef"]] = {a: [] for a in range(len(actors))}  # per actor, in order
    show = _Progress(progress, summary.total, summary.resumed)
    start = time.perf_counter()
    first_start: Dict[int, float] = {}  # actor -> when its first image started (driver's clock)
    last_return: Dict[int, float] = {}  # actor -> when its last image came back

    load = perch2.load_options(config.run_options())  # what a worker's runner reads of an image

    pings: Dict["ray.ObjectRef", int] = {}  # ref -> actor: is a restarted actor back?
    down: Dict[int, float] = {}  # actor -> when to ask again whether it is back

    def submit(a: int):
        while a not in down and queue and len(sent[a]) < queue_per_worker:
            key = queue.pop()
            files = None
            if ship_images:
                try:
                    files = data.read_image_files(key[0], key[1], rgb=load.rgb, depth=load.depth,
                                                  masks_visib=load.masks_visib, masks=load.masks)
                except (perch2.FileError, perch2.InvalidInput) as e:  # as the worker would: this image only
                    summary.skipped[key] = str(e)
                    continue
            ref = actors[a].estimate.remote(key, files)
            in_flight[ref] = (key, a)
            sent[a].append(ref)

    def lost(a: int, why: str):
        """Actor a died. Its images ran in the order sent: those that returned are handled as usual, the
        first that did not was running (it counts an attempt), the rest had not started (re-sent as they are)."""
        summary.restarts += 1
        down[a] = time.perf_counter()  # nothing more goes to it until it answers a ping
        refs, running = list(sent[a]), None
        sent[a].clear()
        back = []
        for r in refs:
            key, _ = in_flight.pop(r)
            try:
                finished(key, a, ray.get(r))
                continue
            except ray.exceptions.RayActorError:
                pass
            if running is None:
                running = key
                attempts[key] = attempts.get(key, 0) + 1
                if attempts[key] >= max_attempts:
                    summary.failed[key] = f"its worker died {attempts[key]} times ({why})"
                    continue
            back.append(key)
        queue.extend(reversed(back))  # popped next, in the order they were sent

    def finished(key: ImageKey, a: int, result: dict) -> bool:
        """Handles a returned image; False if the run must stop (strict and a bad image)."""
        if "error" in result:
            summary.skipped[key] = result["error"]
            if progress is not None:
                progress.write(f"perch2.distributed: skipped scene {key[0]} image {key[1]}: {result['error']}\n")
            if strict:
                return False
        elif not writer.is_done(*key):  # exactly once, whatever came back twice
            now = time.perf_counter()
            first_start.setdefault(a, now - result["wall"])
            last_return[a] = now
            writer.write_image(key[0], key[1], result["rows"])
            summary.done += 1
            summary.per_worker[a] = summary.per_worker.get(a, 0) + 1
            summary.peak_rss_mib[a] = max(summary.peak_rss_mib.get(a, 0.0), result["peak_rss_mib"])
            for name, s in result["stages"]:
                summary.stages[name] = summary.stages.get(name, 0.0) + s
            summary.worker_seconds += result["wall"]
            summary.estimate_seconds += result["seconds"]
        show.show(summary)
        if on_result is not None:
            on_result(result, summary, actors)
        return True

    try:
        for a in range(len(actors)):
            submit(a)
        while in_flight or pings or (queue and down):
            now = time.perf_counter()
            for a, when in list(down.items()):
                if when <= now and a not in pings.values():
                    pings[actors[a].pid.remote()] = a
            ready, _ = ray.wait(list(in_flight) + list(pings), num_returns=1, timeout=0.5)
            if not ready:
                continue
            ref = ready[0]
            if ref in pings:  # a restarted actor: back (take images again) or not yet (ask again soon)
                a = pings.pop(ref)
                try:
                    ray.get(ref)
                    del down[a]
                    submit(a)
                except ray.exceptions.RayActorError:
                    down[a] = time.perf_counter() + 0.5
                continue
            key, a = in_flight[ref]
            try:
                result = ray.get(ref)
            except ray.exceptions.RayActorError as e:
                lost(a, type(e).__name__)
                continue
            del in_flight[ref]
            sent[a].remove(ref)
            if not finished(key, a, result):
                break
            submit(a)
    except KeyboardInterrupt:
        summary.interrupted = True  # every written image is complete; resume picks up the rest
    finally:
        summary.wall_seconds = time.perf_counter() - start
        if first_start:
            summary.startup_seconds = sum(t - start for t in first_start.values()) / len(first_start)
            summary.busy_seconds = sum(last_return[a] - t for a, t in first_start.items())
        for actor in actors:
            ray.kill(actor)
    return summary



def print_summary(summary: RunSummary, out=sys.stdout):
    n = summary.done
    out.write(f"perch2.distributed: {n} images written ({summary.resumed} already complete, "
              f"{len(summary.skipped)} skipped, {len(summary.failed)} failed) in {summary.wall_seconds:.1f} s "
              f"wall; {summary.restarts} worker restart(s)\n")
    if n:
        out.write("  per worker: " + ", ".join(
            f"w{k} {v} images, peak {summary.peak_rss_mib.get(k, 0):.0f} MiB" for k, v in sorted(summary.per_worker.items())) + "\n")
        total = summary.stages.get("total", summary.estimate_seconds)
        out.write("  per-stage seconds summed over workers: " +
                  ", ".join(f"{k} {v:.2f}" for k, v in summary.stages.items()) + "\n")
        over = summary.worker_seconds - summary.estimate_seconds
        out.write(f"  worker time per image {summary.worker_seconds / n:.3f} s, of which outside the estimator "
                  f"{over / n * 1e3:.1f} ms ({100 * over / max(total, 1e-9):.1f}%); "
                  f"{n / max(summary.wall_seconds, 1e-9):.2f} images/s\n")
        steady = summary.busy_seconds - summary.estimate_seconds
        out.write(f"  worker start-up {summary.startup_seconds:.1f} s (Ray, models loaded); while busy, "
                  f"{steady / n * 1e3:.1f} ms per image outside the estimator "
                  f"({100 * steady / max(summary.estimate_seconds, 1e-9):.1f}%: decoding, Python, Ray)\n")
    for key, why in sorted(summary.skipped.items()):
        out.write(f"  skipped scene {key[0]} image {key[1]}: {why}\n")
    for key, why in sorted(summary.failed.items()):
        out.write(f"  failed scene {key[0]} image {key[1]}: {why}\n")


# ---- the command line -------------------------------------------------------------------------------------


def _scene_range(text: str) -> Tuple[int, int]:
    try:
        a, _, b = text.partition("-")
        first, last = int(a), int(b) if b else int(a)
        if first <= last:
            return first, last
    except ValueError:
        pass
    raise argparse.ArgumentTypeError(f"'{text}' is not A-B or A (scene ids, A <= B)")


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perch2.distributed",
                                description="perch2 estimate over a Ray cluster (one actor per worker).")
    sub = p.add_subparsers(dest="command", required=True)
    e = sub.add_parser("estimate", help="estimate a BOP dataset's targets, write one BOP results CSV")
    e.add_argument("--dataset", required=True, help="BOP dataset root (a path every node sees, or --ship-images)")
    e.add_argument("--out", required=True, help="results CSV (the driver writes it; RESULTS.csv.done beside it)")
    e.add_argument("--address", default=None,
                   help="Ray cluster: auto | HOST:PORT; default: start Ray on this machine")
    e.add_argument("--workers", type=int, default=2, help="actors, one estimator each (default 2)")
    e.add_argument("--threads-per-worker", type=int, default=1, help="OpenMP threads = CPUs per actor")
    e.add_argument("--gpus-per-worker", type=float, default=0, help="GPUs per actor (cuda backend)")
    e.add_argument("--ship-images", action="store_true",
                   help="send the dataset's files to the workers (when they do not see --dataset)")
    e.add_argument("--resume", action="store_true", help="estimate only the images not complete in --out")
    e.add_argument("--strict", action="store_true", help="stop at the first bad image")
    e.add_argument("--max-attempts", type=int, default=3,
                   help="an image whose worker died this many times is reported failed (default 3)")
    d = RunConfig()
    e.add_argument("--mode", choices=["3dof", "6dof"], required=True)
    e.add_argument("--variant", default=d.variant)
    e.add_argument("--backend", default=d.backend)
    e.add_argument("--masks", default=d.masks)
    e.add_argument("--box", choices=["full", "visible"], default=d.box)
    e.add_argument("--split", default=d.split)
    e.add_argument("--targets", default=d.targets)
    e.add_argument("--scenes", type=_scene_range, default=None)
    a = p.parse_args(argv)

    def interrupt(signum, frame):  # SIGTERM as Ctrl-C: what is written stays valid; --resume continues
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, interrupt)
    config = RunConfig(mode=a.mode, variant=a.variant, backend=a.backend, masks=a.masks, box=a.box, split=a.split,
                       targets=a.targets, scenes=a.scenes)
    try:
        summary = run(a.dataset, a.out, config, workers=a.workers, threads_per_worker=a.threads_per_worker,
                      gpus_per_worker=a.gpus_per_worker, address=a.address, resume=a.resume, strict=a.strict,
                      ship_images=a.ship_images, max_attempts=a.max_attempts)
    except (perch2.FileError, perch2.InvalidInput, ImportError) as err:
        sys.stderr.write(f"perch2.distributed: {err}\n")
        return 2 if isinstance(err, ImportError) else 1
    print_summary(summary)
    if summary.skipped and a.strict:
        return 1
    return summary.exit_code


if __name__ == "__main__":
    sys.exit(main())
