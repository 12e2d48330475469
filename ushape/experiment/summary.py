"""What a run prints: the composed config as a tree, and at the end where everything went."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from omegaconf import DictConfig, OmegaConf
from rich.console import Console
from rich.tree import Tree

from ushape import atomic

RUN_SUMMARY = "run.json"  # a finished run's record: stage, world, decoder, checkpoint, meshes, seconds


def print_config(cfg: DictConfig, save_to: Path | None = None) -> None:
    """Print the config one branch per group (Rich) and save the same text into the run folder."""
    tree = Tree("config")
    for key in cfg.keys():
        node = cfg[key]
        text = OmegaConf.to_yaml(node, resolve=True) if OmegaConf.is_config(node) else str(node)
        tree.add(f"[bold]{key}[/bold]").add(text.rstrip())
    console = Console(record=True)
    console.print(tree)
    if save_to is not None:
        atomic.write_text(save_to, console.export_text())


def print_summary(summary: Mapping[str, Any], out_dir: Path) -> None:
    lines = [f"Run folder:   {out_dir}"]
    labels = {
        "world": "Data:", "decoder_dir": "Decoder:", "encoder_checkpoint": "Encoder:",
        "tensorboard": "TensorBoard:", "meshes": "Meshes:", "seconds": "Seconds:",
    }
    lines += [f"{label:<13} {summary[key]}" for key, label in labels.items() if key in summary]
    if "tensorboard" in summary:
        lines.append(f"Watch with:   tensorboard --logdir {summary['tensorboard']}")
    Console(soft_wrap=True).print("\n".join(lines), highlight=False)
