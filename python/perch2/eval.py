"""Scoring BOP results against a BOP dataset, as `perch2 eval`: ADD / ADD-S / ADD(-S) AUC (0-10 cm,
YCB-Video toolbox), ADD-S < 1 / 2 cm and the BOP average recalls (VSD, MSSD, MSPD); with BOP 2024 targets
(test_targets_bop24.json, images only) also the 6D detection scores (bop24_mAP).

    report = perch2.eval.evaluate("/data/lm", "results.csv")     # the dict `perch2 eval --json` writes
    report["overall"]["auc_add_or_adds"], report["overall"]["ar"]
    report["detection"]["bop24_mAP"]                             # bop24 targets only
    perch2.eval.plot("/data/lm", "results.csv", "curves.png")    # as `perch2 eval --plot`

ADD(-S) is ADD-S for models with symmetries in models_info.json and ADD otherwise (`auc_add_or_adds`);
`auc_adds` is ADD-S for every model.
"""

import json
import os

from ._perch2 import (  # noqa: F401  (the C++ evaluator, re-exported)
    BopDataset,
    DetectionReport,
    DetectionScores,
    EvalReport,
    EvalSettings,
    InstanceResult,
    Scores,
    evaluate_report,
    format_detection,
    format_report,
    load_results_csv,
    plot_report,
    report_json,
)


def _dataset(dataset, split, targets_file, models_dir):
    if isinstance(dataset, BopDataset):
        return dataset
    root = os.fspath(dataset)
    if not models_dir and os.path.isdir(os.path.join(root, "models_eval")):
        models_dir = "models_eval"  # as `perch2 eval`: bop_toolkit scores on the eval models when present
    return BopDataset(root, split=split, targets_file=targets_file, models_dir=models_dir)


def report(dataset, results, settings=None, split="test", targets_file="", models_dir="", vsd=True,
           vsd_delta_mm=None, progress=None):
    """The perch2.EvalReport of `results` (a results CSV path or a list of perch2.PoseEstimate) on `dataset`
    (a root folder or a perch2.BopDataset). Defaults as `perch2 eval`: models_eval/ when the dataset has it,
    VSD tolerance 15 mm (5 mm for a dataset folder named itodd); vsd=False skips VSD (AR = mean of MSSD and
    MSPD)."""
    data = _dataset(dataset, split, targets_file, models_dir)
    s = settings if settings is not None else EvalSettings()
    if not vsd:
        s.compute_vsd = False
    if os.path.basename(os.path.normpath(data.root())) == "itodd":
        s.vsd_delta_m = 0.005  # eval_bop19_pose.py: 5 mm for ITODD
    if vsd_delta_mm is not None:
        s.vsd_delta_m = vsd_delta_mm * 1e-3
    if isinstance(results, (str, os.PathLike)):
        source, estimates = os.fspath(results), load_results_csv(os.fspath(results))
    else:
        source, estimates = "results", list(results)
    return evaluate_report(data, estimates, s, source, progress), s


def evaluate(dataset, results, settings=None, **options):
    """The evaluation as the dict `perch2 eval --json` writes (settings echoed, "overall", "per_object",
    "instances"; AUCs and recalls in [0, 1]). Options as report()."""
    r, s = report(dataset, results, settings, **options)
    return json.loads(report_json(r, s))


def plot(dataset, results, png_path, settings=None, **options):
    """Evaluates as report() and writes the curves to png_path, as `perch2 eval --plot`: precision against
    recall per object (detection) or accuracy against the ADD(-S) threshold (localization). Returns the
    perch2.EvalReport."""
    r, s = report(dataset, results, settings, **options)
    plot_report(r, s, os.fspath(png_path))
    return r
