"""MODEL_CARD.md of a shipped model: what it was trained on (the splits' rule and exact ids), how (the recipe
and the command that reproduces it), what it scored, and the data's terms."""

from __future__ import annotations

from typing import Any

SPLIT_RULE = (
    "the hash split of the synset's model folders in ShapeNetVox32 (`ushape.data.real.shapenet.hash_split`: "
    "models ordered by the first 8 bytes of SHA-256 of their id, 80 / 10 / 10 %), each split capped to its "
    "first ids in that order (`data.n_train`, `data.n_val`, `data.n_test`); models whose voxels cannot be "
    "read are left out (none were); the exact ids are in splits.json"
)
TERMS = (
    "Trained on ShapeNet (ShapeNetCore v1, through 3D-R2N2's ShapeNetVox32 voxels). ShapeNet's terms of use "
    "apply to the data and to models derived from it: research and non-commercial educational use only "
    "(https://shapenet.org/terms). Cite ShapeNet (Chang et al., 2015) and 3D-R2N2 (Choy et al., 2016)."
)


def model_card(record: dict[str, Any], splits: dict[str, list[str]] | None) -> str:
    """The card's Markdown from model.json's record and the splits (None: the rule only)."""
    sizes = ", ".join(f"{name} {len(ids)}" for name, ids in (splits or {}).items())
    lines = [
        f"# ushape model `{record['name']}`",
        "",
        f"Category: {record.get('category', '?')}. Input: {record['image_size']} px views of the object cut out "
        f"from its background ({record['mask_mode']}). Output: a Gaussian over the {record.get('latent_size', '?')}-d "
        "code of a DeepSDF decoder, decoded to a mesh with its per-vertex SDF std.",
        "",
        "## Data",
        "",
        f"{record.get('data', 'ShapeNetVox32 (3D-R2N2)')}. Splits: {SPLIT_RULE}" + (f" ({sizes})." if sizes else "."),
        "",
        "## Recipe",
        "",
        record.get("recipe", "(not recorded)"),
        "",
        f"Reproduce: `{record.get('command', 'bash notebooks/train_pretrained.sh')}`; exported from "
        f"`{record.get('source_run', '?')}` by `ushape.reconstruction.pretrained.export_pretrained`.",
        "",
        "## Measured",
        "",
    ]
    figures = record.get("figures") or {}
    if figures:
        lines += ["| figure | value |", "|---|---|"] + [f"| {k} | {v} |" for k, v in figures.items()]
    else:
        lines.append("Not measured yet.")
    lines += ["", "## Terms", "", TERMS, ""]
    return "\n".join(lines)
