"""What a run prints: the composed config as a tree, and at the end where everything went."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from omegaconf import DictConfig, OmegaConf
from rich.console import Console
from rich.tree import Tree

from ushape import atomic


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
        "world": "Data:",
        "decoder_dir": "Decoder:",
        "encoder_checkpoint": "Encoder:",
        "tensorboard": "TensorBoard:",
        "meshes": "Meshes:",
        "seconds": "Seconds:",
    }
    lines += [f"{label:<13} {summary[key]}" for key, label in labels.items() if key in summary]
    for row in summary.get("demo", []):
        if row.get("empty"):
            lines.append(f"Demo:         {row['name']}: no surface (see its empty_surface.txt)")
        else:
            lines.append(
                f"Demo:         {row['name']}: {row['views']} view(s){_demo_fusion(row)}, "
                f"latent trace {row['trace']:.3f}, "
                f"mean vertex std {row['std_mean']:.4f}{_demo_scores(row)} -> {row['overview']}"
            )
    uncalibrated = [
        row for row in summary.get("demo", []) if row.get("views", 1) > 1 and not row.get("fusion_calibration")
    ]
    if uncalibrated:
        lines.append(
            f"Note:         the {uncalibrated[0]['views']}-view std treats the views as independent, so it shrinks as "
            "views add up (over-confident on test shapes); fit the shared-error rule on val (~6 min): "
            f"python reconstruct.py --fit-temperature --run {out_dir}   (then reconstruct.py and eval.py use it)"
        )
    if "tensorboard" in summary:
        lines.append(f"Watch with:   tensorboard --logdir {summary['tensorboard']}")
    if "encoder_checkpoint" in summary:
        lines.append(
            f"Next:         python eval.py runs=[{out_dir}]   |   python reconstruct.py your_photo.png --run {out_dir}"
        )
    Console(soft_wrap=True).print("\n".join(lines), highlight=False, markup=False)


def _demo_fusion(row: Mapping[str, Any]) -> str:
    """How a multi-view demo was fused (" fused with shared (calibrated on val)"); "" for one view or old runs."""
    if row.get("views", 1) < 2 or not row.get("fusion"):
        return ""
    how = "calibrated on val" if row.get("fusion_calibration") else "views treated as independent"
    return f" fused with {row['fusion']} ({how})"


def _demo_scores(row: Mapping[str, Any]) -> str:
    """The demo's scores as printed (", IoU 0.41 CD 0.061 (its own code: IoU 0.62)"); "" if not scored."""
    if "iou" not in row:
        return ""
    text = f", IoU {row['iou']:.2f} CD {row['cd']:.3f}"
    own = row.get("own_code")
    return text + (f" (its own code: IoU {own['iou']:.2f})" if own else "")


# What Hydra and `print_config` write into every run folder before any work: no result in them.
BOOKKEEPING = (".hydra", "config_tree.txt")


def discard_if_bookkeeping_only(run_dir: Path) -> bool:
    """Delete a failed run's folder if it holds nothing but bookkeeping (Hydra's config, logs); True if it did.

    A run that fails before producing anything (a bad config, a missing dataset) would otherwise
    leave an empty-looking folder that `eval.py` and `reconstruct.py` then have to skip.
    """
    if not run_dir.is_dir():
        return False
    for path in run_dir.rglob("*"):
        relative = path.relative_to(run_dir)
        if (
            path.is_file()
            and relative.parts[0] not in BOOKKEEPING
            and not (len(relative.parts) == 1 and path.suffix == ".log")
        ):
            return False
    import shutil

    shutil.rmtree(run_dir, ignore_errors=True)
    for parent in (run_dir.parent, run_dir.parent.parent):  # the day's folder and runs/, if now empty
        try:
            parent.rmdir()
        except OSError:
            break
    return True
