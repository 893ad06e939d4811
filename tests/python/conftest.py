"""Shared fixtures: the perch2 CLI (to compare with) and tiny generated BOP datasets.

Run through ctest (./run.sh test), which sets PYTHONPATH to the built package and PERCH2_CLI to the built
command-line tool; or by hand: PYTHONPATH=build/python PERCH2_CLI=build/examples/perch2 pytest tests/python
"""

import os
import pathlib
import subprocess

import pytest

SOURCE = pathlib.Path(os.environ.get("PERCH2_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))


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


def _generated(cli, mode, tmp_path_factory):
    out = tmp_path_factory.mktemp(f"generated_{mode}")
    run(cli, "generate", "--mode", mode, "--scenes", "1", "--images-per-scene", "2", "--objects", "2", "--seed", "5",
        "--out", out)
    return out


@pytest.fixture(scope="session")
def dataset_3dof(cli, tmp_path_factory):
    """1 scene, 2 images, 2 objects on a table (seed 5), as tests/cli_estimate_smoke.cmake uses."""
    return _generated(cli, "3dof", tmp_path_factory)


@pytest.fixture(scope="session")
def dataset_6dof(cli, tmp_path_factory):
    return _generated(cli, "6dof", tmp_path_factory)


@pytest.fixture
def tmp_out(tmp_path_factory):
    return tmp_path_factory.mktemp("out", numbered=True)
