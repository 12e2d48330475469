"""Every option of every config group composes, and every `_target_` it names can be imported."""

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import get_object
from omegaconf import DictConfig, ListConfig, OmegaConf

CONF = Path(__file__).resolve().parents[1] / "conf"
# Groups whose options are chosen on the command line (hydra's own group is composed separately; eval.py
# reads conf/method/ by name, as `methods=[refine_masks, ...]`: a list, not one option of a group; the
# planning loop reads conf/strategy/ and conf/observer/ by name: tests/planning/test_plugins.py; propagation reads
# conf/propagation/ by name: tests/propagation/test_propagation_methods.py).
NAMED_LISTS = {"method", "strategy", "observer", "propagation"}
GROUPS = sorted(p.name for p in CONF.iterdir() if p.is_dir() and p.name not in {"hydra", *NAMED_LISTS})


def _options(group: str) -> list[str]:
    return sorted(p.stem for p in (CONF / group).glob("*.yaml"))


def _targets(node, path=""):
    if isinstance(node, DictConfig):
        for key in node.keys():
            value = node._get_node(key)
            if key == "_target_":
                yield path, node[key]
            else:
                yield from _targets(value, f"{path}.{key}" if path else str(key))
    elif isinstance(node, ListConfig):
        for i, value in enumerate(node):
            yield from _targets(value, f"{path}[{i}]")


# Groups only eval.py's config uses; every other group belongs to train.py's.
EVAL_ONLY = {"protocol"}


def _compose(overrides: list[str], hydra_cfg: bool = False, config: str = "train") -> DictConfig:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config, overrides=overrides, return_hydra_config=hydra_cfg)


ALL = [(g, o) for g in GROUPS for o in _options(g)]


def test_every_group_has_options():
    assert {
        "category",
        "data",
        "decoder",
        "encoder",
        "loss",
        "fusion",
        "crop",
        "trainer",
        "logger",
        "experiment",
        "paths",
    } <= set(GROUPS)
    assert not [g for g in GROUPS if not _options(g)]


@pytest.mark.parametrize("group,option", ALL, ids=[f"{g}={o}" for g, o in ALL])
def test_option_composes_and_targets_import(group, option, tmp_path):
    config = "eval" if group in EVAL_ONLY else "train"
    paths = [f"paths.root_dir={tmp_path}", f"paths.output_dir={tmp_path}/run"]
    if config == "eval":
        paths.append(f"out_dir={tmp_path}/eval")
    cfg = _compose([f"{group}={option}", *paths], config=config)
    OmegaConf.resolve(cfg)
    for where, target in _targets(cfg):
        assert get_object(target) is not None, f"{group}={option}: {where}._target_={target} does not import"


def test_unknown_option_lists_the_valid_ones():
    with pytest.raises(Exception) as err:
        _compose(["category=sofas"])
    assert "chairs" in str(err.value) and "tables" in str(err.value)


def test_eval_config_composes_with_sweepable_fusion_and_crop():
    cfg = _compose(["fusion=bayesian_k", "fusion.k=4", "crop.min_scale=0.1"], config="eval")
    assert cfg.fusion.k == 4 and cfg.crop.min_scale == 0.1


def test_slurm_launcher_composes():
    cfg = _compose(["hydra/launcher=slurm"], hydra_cfg=True)
    assert cfg.hydra.launcher._target_.endswith("SlurmLauncher")
    assert cfg.hydra.launcher.gpus_per_node == 1


def test_fusion_k_and_crop_are_sweepable_keys():
    cfg = _compose(["fusion=bayesian_k", "fusion.k=2", "crop.min_scale=0.1"])
    assert cfg.fusion.k == 2 and cfg.crop.min_scale == 0.1


@pytest.mark.parametrize("name", sorted(p.stem for p in (CONF / "method").glob("*.yaml")))
def test_every_method_file_builds_a_method(name):
    from ushape.evaluation.methods import ReconstructionMethod, build_methods

    (method,) = build_methods([name])
    assert isinstance(method, ReconstructionMethod) and method.name == name


def test_eval_config_takes_methods_by_name_and_by_target():
    from ushape.evaluation.methods import build_methods

    target = "{_target_: ushape.evaluation.refine_method.RefineMethod, mode: depth, size: 8, name: coarse}"
    cfg = _compose([f"methods=[refine_masks,{target}]"], config="eval")
    masks, coarse = build_methods(list(cfg.methods))
    assert (masks.label, masks.settings.observation.size) == ("refine (masks)", 32)
    assert (coarse.name, coarse.settings.mode, coarse.settings.observation.size) == ("coarse", "depth", 8)
    with pytest.raises(ValueError, match="refine_masks"):
        build_methods(["refine_mask"])
