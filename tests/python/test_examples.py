"""The Python examples (examples/python/) run and say what they should, on the generated datasets (the
README's and docs' Python blocks run in the docs check, tests/docs_check.py)."""

import os
import pathlib
import sys

from conftest import run
from test_estimators import target_detections

EXAMPLES = pathlib.Path(__file__).resolve().parents[2] / "examples" / "python"


def example(name, *args, **kw):
    return run(sys.executable, EXAMPLES / name, *args, **kw).stdout


def test_tabletop_on_a_generated_scene(cli, tmp_out):
    out = run(sys.executable, EXAMPLES / "tabletop_generated.py", env=dict(os.environ, PERCH2_CLI=str(cli))).stdout
    assert out.count("mm from the ground truth") == 3, out


def test_sixdof_bop_with_a_detection_file(dataset_6dof, tmp_out):
    dets = target_detections(dataset_6dof, tmp_out / "dets.json")
    out = example("sixdof_bop.py", "--dataset", dataset_6dof, "--detections", dets, "--out", tmp_out / "r.csv",
                  "--eval")
    assert "poses ->" in out and "ADD(-S) AUC" in out, out
    assert (tmp_out / "r.csv").read_text().startswith("scene_id,im_id,obj_id,score,R,t,time")


def test_bring_your_own_detector(dataset_6dof):
    out = example("bring_your_own_detector.py", "--dataset", dataset_6dof, "--backend", "cpu")
    lines = [l for l in out.splitlines() if "mm from the ground truth" in l]
    assert len(lines) >= 2, out
    for l in lines:  # ground-truth masks on an easy generated scene: every pose within 2 cm
        assert float(l.split(",")[-1].split()[0]) < 20, l


def test_render_hypotheses(tmp_out):
    out = example("render_hypotheses.py", "--out", tmp_out / "h.png")
    assert "8 hypotheses" in out
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        assert "matplotlib is not installed: plot skipped" in out
    else:
        assert (tmp_out / "h.png").exists()
