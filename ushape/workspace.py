"""The names of what ushape leaves on disk, in one place (as DeepSDF's workspace.py keeps them).

outputs/runs/<date>/<time>_<stage>_<category>[_<loss>]/    one `python train.py` run
    run.json                 the finished run's record (stage, world, decoder, checkpoint, seconds)
    .hydra/config.yaml       the composed config
    checkpoints/best.ckpt    stage 2: the best validation epoch
    checkpoints/last.ckpt    the newest epoch, rewritten every epoch (what a resume starts from)
    temperature.json         stage 2: the variance temperature fitted on val (reconstruct.py --fit-temperature)
    refinement_calibration.json   the refinement's calibration (reconstruct.py --fit-refinement)
    viewpoint.pt             the camera-azimuth head on the frozen features (reconstruct.py --fit-viewpoint)
    pose_calibration.json    the pose posterior's information scale (reconstruct.py --fit-pose)
    meshes/scores.json       the training demo's reconstructions and their scores
outputs/multirun/<sweep>/<job>/                           the same, one folder per sweep job
outputs/decoders/<category>-<hash>/                       one stage-1 decoder
    decoder.pt, codes_<split>.pt, DONE, report.json, basis.pt
outputs/data/<kind>/<category>-<hash>/                    one data world
    config.json, renders/<shape>/views.npz, skipped.json (real worlds: models left out, and why)
<run>/eval/<time>/                                        one `python eval.py`
    results.json, eval_row.json, tables.md, report.html
<reconstruct --out>/                                      one `python reconstruct.py` (and `active.py`)
    summary.json, report.html, .reconstruct.lock
ushape/pretrained/<name>/                                 one shipped model
    model.json, encoder.ckpt, decoder/, MODEL_CARD.md, splits.json
"""

from __future__ import annotations

from pathlib import Path

# The Hydra configs. Shipped inside the package (ushape/conf links to the checkout's top-level conf/,
# and the wheel carries the files), so an installed ushape finds them wherever it runs.
CONFIG_DIR = Path(__file__).resolve().parent / "conf"
OUTPUTS_DIR = "outputs"  # every run, decoder and data cache lives under one outputs/ folder (conf/paths)
RUNS_DIR = Path(OUTPUTS_DIR) / "runs"
MULTIRUN_DIR = Path(OUTPUTS_DIR) / "multirun"
RUN_SUMMARY = "run.json"
HYDRA_CONFIG = Path(".hydra") / "config.yaml"
CHECKPOINT_DIR = "checkpoints"
BEST_NAME = "best"
LAST_FILE = "last.ckpt"
BEST_FILE = f"{BEST_NAME}.ckpt"
TEMPERATURE_FILE = "temperature.json"
CALIBRATION_FILE = "refinement_calibration.json"
VIEWPOINT_FILE = "viewpoint.pt"
POSE_CALIBRATION_FILE = "pose_calibration.json"
SCORES_FILE = "scores.json"

# A stage-1 decoder's folder.
DECODER_FILE = "decoder.pt"
DONE_FILE = "DONE"
FITTED_FILE = "FITTED"  # the epochs are done: decoder and training codes written, held-out codes may follow
DECODER_REPORT_FILE = "report.json"
BASIS_FILE = "basis.pt"
IDENTITY_FILE = "identity.json"  # the config the decoder's folder hash was made from

# A data world's folder.
CONFIG_FILE = "config.json"
VIEWS_FILE = "views.npz"
SKIPPED_FILE = "skipped.json"

# An evaluation's folder.
RESULTS = "results.json"
RESULT_ROW = "eval_row.json"
TABLES_FILE = "tables.md"  # every table of an evaluation, in Markdown

# A reconstruction's folder (and an evaluation's page).
SUMMARY_FILE = "summary.json"
REPORT_FILE = "report.html"
LOCK_FILE = ".reconstruct.lock"

# A shipped model's folder.
MODEL_FILE, ENCODER_FILE, DECODER_DIR, CARD_FILE = "model.json", "encoder.ckpt", "decoder", "MODEL_CARD.md"
SPLITS_FILE = "splits.json"  # the exact shape ids of the model's train, val and test splits


def relocated(recorded: str | Path, run_dir: Path | None) -> Path:
    """A path recorded when `run_dir` was trained, found again if outputs/ has moved since.

    Paths under outputs/ (the world, the stage-1 decoder) are looked up at the same place under the
    outputs/ folder that holds `run_dir` now; a relative one recorded against the working directory
    of the time is read against that outputs/ folder's parent. Anything else is returned as recorded.
    """
    path = Path(recorded)
    if path.is_absolute() and path.exists() or run_dir is None:
        return path
    outputs = next((p for p in (run_dir.resolve(), *run_dir.resolve().parents) if p.name == OUTPUTS_DIR), None)
    if outputs is not None and OUTPUTS_DIR in path.parts:
        tail = path.parts[len(path.parts) - path.parts[::-1].index(OUTPUTS_DIR) :]
        candidate = outputs.joinpath(*tail)
        if candidate.exists():
            return candidate
    return path
