"""What `python eval.py` does with its composed config: gather a sweep, or evaluate runs and write results."""

from __future__ import annotations

import logging
import time
from pathlib import Path

from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from ushape.builders import build
from ushape.errors import bad_input_exit
from ushape.evaluation.methods import build_methods
from ushape.evaluation.page import evaluation_page
from ushape.evaluation.plugin import load_protocols
from ushape.evaluation.report import write_results
from ushape.evaluation.runner import evaluate_runs
from ushape.evaluation.settings import PAPER_PROTOCOLS, Settings
from ushape.evaluation.showcase import Showcase
from ushape.evaluation.sources import resolve_runs
from ushape.reconstruction.pretrained import PREFIX
from ushape.training.summary import discard_if_bookkeeping_only
from ushape.training.validation import check_config

log = logging.getLogger(__name__)


def protocols_for(requested, multirun: bool) -> list[str]:
    """`auto`: every paper protocol in a single run (not `active`: ask for it by name); none in a sweep's job
    (each job is one fusion/crop row)."""
    if requested == "auto":
        return [] if multirun else list(PAPER_PROTOCOLS)
    if isinstance(requested, str):
        requested = [requested]
    return list(requested)


def _multirun() -> bool:
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def configured_setting(cfg: DictConfig):
    """(fusion callable, its table name, crop min scale) from the `fusion` and `crop` groups."""
    fuse = instantiate(cfg.fusion)
    name = getattr(fuse, "name", type(fuse).__name__)
    return fuse, name, float(cfg.crop.min_scale)


def default_out_dir(runs: list[Path]) -> Path:
    """Where results go when out_dir is not given: a multirun job's own folder (a sweep gathers them);
    otherwise into the evaluated run (<run>/eval/<time>), or the sweep folder its runs share."""
    from hydra.core.hydra_config import HydraConfig

    if _multirun() or not runs or any(str(r).startswith(PREFIX) for r in runs):  # a shipped model has no run folder
        return Path(HydraConfig.get().runtime.output_dir)
    parents = {Path(r).resolve().parent for r in runs}
    home = Path(runs[0]).resolve() if len(runs) == 1 else (parents.pop() if len(parents) == 1 else None)
    if home is None:  # runs from different places: Hydra's own folder under outputs/eval
        return Path(HydraConfig.get().runtime.output_dir)
    return home / "eval" / time.strftime("%Y-%m-%d_%H-%M-%S")


def evaluated_world(cfg: DictConfig) -> str | None:
    """The world folder to evaluate on: `world=<folder>`, or the `data` group's world built (or found in
    its cache) here, e.g. `data=pix3d data.root=...`; None: each run's own world (its run.json)."""
    if cfg.get("data") is None:
        return cfg.get("world")
    if cfg.get("world"):
        raise ValueError("give the evaluated world either as world=<folder> or as data=<group>, not both")
    started = time.time()
    world = instantiate(cfg.data).build()
    log.info(
        "evaluation world ready in %.1f s: %s (test %d shapes)",
        time.time() - started,
        world.root,
        len(world.shape_ids("test")),
    )
    return str(world.root)


def run_eval(cfg: DictConfig) -> float | None:
    """Evaluate (or gather); returns the configured setting's mean multi-view IoU (what a sweeper maximises).

    A bad config is one error line and exit code 2; a failed evaluation leaves no empty Hydra folder.
    """
    hydra_dir = OmegaConf.select(cfg, "paths.output_dir", default=None, throw_on_resolution_failure=False)
    try:
        check_config(cfg)
        return _evaluate(cfg)
    except BaseException as err:
        if hydra_dir is not None:
            discard_if_bookkeeping_only(Path(hydra_dir))
        stop = bad_input_exit(err)
        if stop is not None:
            raise stop from None
        raise


def _evaluate(cfg: DictConfig) -> float | None:
    if cfg.get("gather"):
        from ushape.evaluation.gather import gather

        markdown = gather(cfg.gather)
        print(markdown.read_text())
        return None
    settings = build(cfg.protocol, Settings)
    protocols = load_protocols(
        protocols_for(cfg.protocols, _multirun()), cfg.get("plugins"), list(cfg.get("protocol_dirs") or [])
    )
    given = cfg.get("runs") or cfg.get("sweep")
    runs = resolve_runs(cfg.get("runs"), cfg.get("sweep"), "." if given else cfg.paths.root_dir)
    out_dir = Path(cfg.out_dir) if cfg.get("out_dir") else default_out_dir(runs)
    world_dir = evaluated_world(cfg)
    log.info("evaluating %d run(s) into %s: %s", len(runs), out_dir, ", ".join(map(str, runs)))
    result = evaluate_runs(
        runs,
        settings,
        Path(cfg.cache_dir) if cfg.get("cache_dir") else None,
        setting=configured_setting(cfg),
        world_dir=world_dir,
        showcase_dir=out_dir if protocols else None,
        temperature=bool(cfg.get("temperature", False)),
        protocols=protocols,
        methods=build_methods(list(cfg.get("methods") or [])),
        showcase=build(cfg.get("showcase"), Showcase),
    )
    paths = write_results(result, out_dir, tensorboard=cfg.tensorboard)
    page = evaluation_page(out_dir, f"evaluation of {', '.join(str(r) for r in runs)}")
    if "tables" in paths:
        print(paths["tables"].read_text())
    for row in result["rows"]:
        print(
            f"{row['label']:>10} {row['fusion']:>12} min_scale {row['min_scale']:g}: single-view IoU "
            f"{row['single_view_iou']:.4f}, {row['group_size']}-view IoU {row['multi_view_iou']:.4f}"
        )
    print(f"Evaluation written to {out_dir} ({result['seconds']} s); open {page} in a browser")
    rows = result["rows"]
    return sum(r["multi_view_iou"] for r in rows) / len(rows) if rows else None
