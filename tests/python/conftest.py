"""Shared fixtures: the perch2 CLI (to compare with), tiny generated BOP datasets, the shared real data.

Run through ctest (./run.sh test), which sets PYTHONPATH to the built package and PERCH2_CLI to the built
command-line tool; or by hand: PYTHONPATH=build/python PERCH2_CLI=build/examples/perch2 pytest tests/python
"""

import os
import pathlib
import subprocess

import pytest

SOURCE = pathlib.Path(os.environ.get("PERCH2_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))


def _tmp_root():
    root = pathlib.Path(os.environ.get("PERCH2_TEST_TMP", SOURCE / "build" / "tests" / "python_tmp"))
    root.mkdir(parents=True, exist_ok=True)
    return root


@pytest.fixture(scope="session")
def cli():
    path = os.environ.get("PERCH2_CLI") or str(SOURCE / "build" / "examples" / "perch2")
    if not os.path.exists(path):
        pytest.skip(f"the perch2 command-line tool is not built ({path}); build with PERCH2_BUILD_EXAMPLES=ON")
    return path


def run(*args, **kw):
    """Runs a command; on failure the assertion shows its output."""
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True, **kw)
    assert p.returncode == 0, f"{args} failed ({p.returncode}):\n{p.stdout}\n{p.stderr}"
    return p


def _generated(cli, mode, tmp_name):
    # Session-scoped per pytest process; each ctest test is its own process, so the datasets are per file.
    out = _tmp_root() / f"{tmp_name}_{os.getpid()}"
    if not (out / "models").exists():
        run(cli, "generate", "--mode", mode, "--scenes", "1", "--images-per-scene", "2", "--objects", "2",
            "--seed", "5", "--out", out)
    return out


@pytest.fixture(scope="session")
def dataset_3dof(cli):
    return _generated(cli, "3dof", "gen3dof")


@pytest.fixture(scope="session")
def dataset_6dof(cli):
    return _generated(cli, "6dof", "gen6dof")


@pytest.fixture
def tmp_out(tmp_path_factory):
    return tmp_path_factory.mktemp("out", numbered=True)


@pytest.fixture(scope="session")
def shared_data():
    d = pathlib.Path(os.environ.get("PERCH2_SHARED_DATA_DIR", SOURCE.parent / "shared" / "data"))
    if not d.is_dir():
        pytest.skip(f"the shared data ({d}) is not beside the checkout")
    return d
