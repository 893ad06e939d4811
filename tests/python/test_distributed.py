"""perch2.distributed on a real local Ray cluster (2 CPUs, two actors of one OpenMP thread each) over a generated
BOP dataset: the same rows as `perch2 estimate`, a worker killed mid-run, the driver killed and resumed, images
shipped as bytes, a bad image skipped, an image that kills its workers reported failed. Skipped when Ray is not
installed (pip install 'ray[default]'; ./run.sh test installs it into the test venv)."""

import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import pytest

from conftest import run

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'ray[default]'): distributed tests skipped")

import perch2  # noqa: E402
import perch2.distributed as pd  # noqa: E402


@pytest.fixture(scope="module")
def cluster():
    """One local Ray instance for the module: 2 CPUs, as CI has."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray.get_runtime_context().gcs_address
    ray.shutdown()


@pytest.fixture(scope="module")
def dataset(cli, tmp_path_factory):
    """Six 6-DoF images (3 scenes x 2), small enough for seconds of estimation per run."""
    out = tmp_path_factory.mktemp("dist6dof")
    run(cli, "generate", "--mode", "6dof", "--scenes", "3", "--images-per-scene", "2", "--objects", "2",
        "--seed", "11", "--out", out)
    return out


def rows_of(path):
    """The results as comparable lines: every column but the time."""
    lines = pathlib.Path(path).read_text().splitlines()
    return sorted(",".join(line.split(",")[:6]) for line in lines[1:] if line)


@pytest.fixture(scope="module")
def cli_rows(cli, dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "results.csv"
    run(cli, "estimate", "--mode", "6dof", "--dataset", dataset, "--out", out, env=dict(os.environ, OMP_NUM_THREADS="1"))
    rows = rows_of(out)
    assert len(rows) >= 6
    return rows


CONFIG = pd.RunConfig(mode="6dof")


def done_images(path):
    lines = pathlib.Path(str(path) + ".done").read_text().splitlines()[1:]
    return [tuple(map(int, line.split(",")[:2])) for line in lines if line]


def test_same_rows_as_the_cli(cluster, dataset, cli_rows, tmp_out):
    out = tmp_out / "results.csv"
    s = pd.run(str(dataset), str(out), CONFIG, workers=2, address=cluster, progress=None)
    assert s.exit_code == 0 and s.done == s.total == 6 and not s.skipped and not s.failed
    assert rows_of(out) == cli_rows
    assert sorted(done_images(out)) == sorted(set(done_images(out)))  # each image once
    assert sum(s.per_worker.values()) == 6 and len(s.per_worker) == 2  # both workers pulled images
    assert s.stages["total"] == pytest.approx(s.estimate_seconds, rel=1e-6)


def test_images_shipped_as_bytes_give_the_same_rows(cluster, dataset, cli_rows, tmp_out):
    out = tmp_out / "results.csv"
    s = pd.run(str(dataset), str(out), CONFIG, workers=2, address=cluster, ship_images=True, progress=None)
    assert s.exit_code == 0 and s.done == 6
    assert rows_of(out) == cli_rows


def test_a_worker_killed_mid_run_loses_no_image(cluster, dataset, cli_rows, tmp_out):
    out = tmp_out / "results.csv"
    killed = []

    def kill_once(result, summary, actors):  # the first worker to return an image dies with its next one
        if not killed:
            killed.append(result["pid"])
            os.kill(result["pid"], signal.SIGKILL)

    s = pd.run(str(dataset), str(out), CONFIG, workers=2, address=cluster, progress=None, on_result=kill_once)
    assert killed and s.restarts >= 1
    assert s.exit_code == 0 and s.done == 6 and not s.failed
    assert rows_of(out) == cli_rows
    assert len(done_images(out)) == 6


def test_an_image_that_kills_its_workers_is_reported_failed(cluster, dataset, cli_rows, tmp_out):
    out = tmp_out / "results.csv"
    deadly = tuple(int(v) for v in cli_rows[0].split(",")[:2])  # the first image

    # Every worker process that starts `deadly` SIGKILLs itself (as a segfault or an out-of-memory kill would).
    s = pd.run(str(dataset), str(out), CONFIG, workers=2, address=cluster, progress=None, max_attempts=2,
               _worker_dies_on=deadly)
    assert list(s.failed) == [deadly] and "died 2 times" in s.failed[deadly]
    assert s.done == 5 and s.exit_code == 3
    assert rows_of(out) == [r for r in cli_rows if not r.startswith("%d,%d," % deadly)]
    assert deadly not in done_images(out)


def test_a_bad_image_costs_only_that_image(cluster, dataset, cli_rows, tmp_out):
    broken = tmp_out / "broken"
    shutil.copytree(dataset, broken)
    scene, im = (int(v) for v in cli_rows[-1].split(",")[:2])  # the last image
    depth = broken / "test" / f"{scene:06d}" / "depth" / f"{im:06d}.png"
    depth.write_bytes(depth.read_bytes()[:200])  # truncated
    out = tmp_out / "results.csv"
    s = pd.run(str(broken), str(out), CONFIG, workers=2, address=cluster, progress=None)
    assert list(s.skipped) == [(scene, im)] and str(depth.relative_to(broken)) in s.skipped[(scene, im)]
    assert s.done == 5 and s.exit_code == 3
    assert rows_of(out) == [r for r in cli_rows if not r.startswith(f"{scene},{im},")]


def test_driver_killed_then_resumed_gives_the_same_csv(cluster, dataset, cli_rows, tmp_out):
    out = tmp_out / "results.csv"
    cmd = [sys.executable, "-m", "perch2.distributed", "estimate", "--dataset", str(dataset), "--out", str(out),
           "--mode", "6dof", "--workers", "2", "--address", cluster]
    driver = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    deadline = time.time() + 300
    while time.time() < deadline and driver.poll() is None:
        if os.path.exists(str(out) + ".done") and len(done_images(out)) >= 2:
            break
        time.sleep(0.05)
    assert driver.poll() is None, "the driver finished before it could be killed: " + driver.stdout.read().decode()
    driver.kill()  # SIGKILL: no clean-up of any kind
    driver.wait()
    first = len(done_images(out))
    assert 2 <= first < 6
    p = run(*cmd, "--resume")
    assert f"{first} already complete" in p.stdout
    assert rows_of(out) == cli_rows
    assert sorted(done_images(out)) == sorted(set(done_images(out))) and len(done_images(out)) == 6


def test_bad_arguments_raise_named_errors(cluster, dataset, tmp_out):
    with pytest.raises(perch2.InvalidInput, match="workers"):
        pd.run(str(dataset), str(tmp_out / "r.csv"), CONFIG, workers=0, address=cluster, progress=None)
    with pytest.raises(perch2.InvalidInput, match="gpus_per_worker"):
        pd.run(str(dataset), str(tmp_out / "r.csv"), pd.RunConfig(mode="6dof", backend="cuda"), address=cluster,
               progress=None)
    with pytest.raises(perch2.FileError):
        pd.run(str(tmp_out / "no_such"), str(tmp_out / "r.csv"), CONFIG, address=cluster, progress=None)
