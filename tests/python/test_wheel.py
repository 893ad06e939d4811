"""`pip wheel .` makes a wheel that installs into a fresh virtual environment and imports there, without
the build tree (a second compile of the libraries; its build folder keeps it incremental between runs)."""

import os
import pathlib
import shutil
import subprocess
import sys
import venv

import pytest

SOURCE = pathlib.Path(__file__).resolve().parents[2]

CHECK = r"""
import numpy as np, os, perch2, sys
assert os.path.dirname(perch2.__file__).startswith(sys.prefix), perch2.__file__
v = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0]], float)
m = perch2.Mesh(v, [[0, 2, 1]])  # facing the camera (-z)
T = np.eye(4); T[2, 3] = 0.5
c = perch2.Renderer([m], backend="thrust_omp").render(0, T, perch2.Intrinsics(100, 100, 32, 24, 64, 48))
assert len(c) > 0
d = os.path.dirname(perch2.__file__)
assert os.path.exists(os.path.join(d, "_perch2.pyi")) and os.path.exists(os.path.join(d, "py.typed"))
print("wheel ok", perch2.__version__, len(c), sorted(f for f in os.listdir(d) if f.startswith("libperch2")))
"""


def test_wheel_installs_into_a_clean_venv_and_imports(tmp_path):
    for module in ("scikit_build_core", "nanobind"):
        try:
            __import__(module)
        except ImportError:
            pytest.skip(f"{module} is not installed in this Python (./run.sh python installs it)")
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if shutil.which("ccache"):
        env.setdefault("CMAKE_CXX_COMPILER_LAUNCHER", "ccache")  # read by CMake as the launcher's default
    wheels = tmp_path / "wheels"
    build_dir = ["-C", f"build-dir={env['PERCH2_WHEEL_BUILD_DIR']}"] if env.get("PERCH2_WHEEL_BUILD_DIR") else []
    p = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", wheels,
                        *build_dir, SOURCE], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stdout[-4000:] + p.stderr[-4000:]
    (wheel,) = wheels.glob("perch2-*.whl")
    clean = tmp_path / "venv"
    venv.create(clean, with_pip=True)
    py = clean / "bin" / "python"
    p = subprocess.run([py, "-m", "pip", "install", "-q", wheel], capture_output=True, text=True, env=env)
    assert p.returncode == 0, p.stdout[-4000:] + p.stderr[-4000:]
    p = subprocess.run([py, "-c", CHECK], capture_output=True, text=True, env=env, cwd=tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    assert "wheel ok" in p.stdout
