"""Where the active protocol keeps each finished sequence, so a long Table A run resumes where it stopped.

A sequence (one shape, crop setting, observer and strategy) costs minutes when its belief is refined after
every view, and the full protocol hours a category; an evaluation stopped half way (a session's end, a
crash) would otherwise start again from its first shape. Each sequence's scored steps and its Table A-why
row are written, atomically, under the evaluation's cache folder (`cache_dir`, `null` keeps none) as soon as
it ends, keyed by everything that decides them:

- the encoder (checkpoint and temperature), the decoder, the world, the shape and its own code (the oracle
  and Table A-why's realised drops read it; a world whose test codes the evaluation fits, e.g. Pix3D, refits
  them with its settings);
- the crop min scale, the observer, the strategy;
- the settings a sequence reads (seed, split, views to take, candidates, rays and LM steps of the refinement,
  mesh resolution and scoring points, decoder precision), not those that only choose which sequences run
  (the plan's `strategies`, `observe`, `scales`, `shapes`): a larger run reuses a smaller
  one's sequences;
- the bytes of the run's temperature.json and refinement_calibration.json (the calibrated prior a refined
  belief starts from, information-seen's floors): refitting either runs the sequences again;
- `VERSION`, raised when the loop or a strategy changes what a sequence returns.

A cached step keeps the seconds it took when it ran. A cache file that cannot be read is reported and
computed again, never trusted.
"""

from __future__ import annotations

import hashlib
import json
import logging
from pathlib import Path

from torch import Tensor

from ushape import atomic
from ushape.evaluation.views import encoder_tag
from ushape.reconstruction.predictor import temperature_path
from ushape.reconstruction.refine_calibration import calibration_path

log = logging.getLogger(__name__)

CACHE_FOLDER = "active"
VERSION = 2  # 2: the oracle under a refining observer scores the refined belief, not the fused code
# The settings a sequence's result depends on (the others choose which sequences run, or other protocols):
# the evaluation's shared ones, and the plan's (keyed as active_<name>, the spelling keys were made with).
SEQUENCE_SETTINGS = ("split", "seed", "resolution", "n_points", "precision")
SEQUENCE_PLAN = ("views", "candidates", "azimuths", "elevations", "refine_size", "refine_iterations")


def file_digest(path: Path) -> str:
    """sha1 of a file's bytes ("absent" where there is no file)."""
    return hashlib.sha1(path.read_bytes()).hexdigest() if path.is_file() else "absent"


def sequence_file(
    cache_dir: Path | None,
    run,
    settings,
    plan,
    shape_id: str,
    true_code: Tensor,  # [D] the shape's own code
    scale: float,
    observe: str,
    strategy: str,
) -> Path | None:
    """Where one sequence's result is kept (None: the evaluation keeps no cache)."""
    if cache_dir is None:
        return None
    checkpoint = run.predictor.checkpoint
    parts = [
        f"v{VERSION}",
        encoder_tag(run.predictor),
        run.reconstructor.decoder_tag,
        str(Path(run.world.root).resolve()),
        shape_id,
        hashlib.sha1(true_code.detach().float().cpu().numpy().tobytes()).hexdigest(),
        f"{float(scale):g}",
        observe,
        strategy,
        *(f"{name}={getattr(settings, name)!r}" for name in SEQUENCE_SETTINGS),
        *(f"active_{name}={getattr(plan, name)!r}" for name in SEQUENCE_PLAN),
        file_digest(temperature_path(checkpoint)),
        file_digest(calibration_path(checkpoint)),
    ]
    key = hashlib.sha1("|".join(parts).encode()).hexdigest()[:24]
    return Path(cache_dir) / CACHE_FOLDER / f"{key}.json"


def load_sequence(path: Path | None) -> dict | None:
    """A kept sequence {"steps": [...], "spread": float, "decisions": [...]}, or None (none kept, or unreadable)."""
    if path is None or not path.is_file():
        return None
    try:
        blob = json.loads(path.read_text())
        if not isinstance(blob, dict) or not {"steps", "spread", "decisions"} <= set(blob):
            raise ValueError("not a sequence: it needs steps, spread and decisions")
        return blob
    except (ValueError, OSError) as error:  # json.JSONDecodeError is a ValueError
        log.warning("active protocol: cannot read the cached sequence %s (%s); computing it again", path, error)
        return None


def store_sequence(path: Path | None, steps: list[dict], spread: float, decisions: list[dict]) -> None:
    """Keep a finished sequence: its scored steps (records without the row's names), spread and decisions."""
    if path is not None:
        # Not sorted (atomic.write_json sorts): the records come back in the order they were made.
        atomic.write_text(path, json.dumps({"steps": steps, "spread": spread, "decisions": decisions}) + "\n")
