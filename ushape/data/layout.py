"""Where every file of a cached synthetic world lives (every name is defined here, nowhere else).

<root>/<category>-<hash12>/
  config.json                          the generating config (hash12 is its hash); worlds whose shapes
                                       have different numbers of views list them in views_per_shape
  splits/train.json, val.json, test.json   JSON lists of shape ids
  meshes/<shape_id>.ply                normalised watertight mesh
  sdf/<shape_id>.npz                   pos [P,4], neg [Q,4] float32 (DeepSDF layout)
  renders/<shape_id>/00.png .. NN.png  RGBA, transparent background
  renders/<shape_id>/rendering_metadata.txt   "az el inplane dist_ratio fov" per view
  renders/<shape_id>/views.npz         K [V,3,3], world_to_cam [V,4,4], masks [V,H,W] bool,
                                       depth [V,H,W] float32, r2n2_centre [3], r2n2_scale []
  shapes/<shape_id>.json               the shape's style dict + seed
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ushape.workspace import CONFIG_FILE, VIEWS_FILE

SPLITS_DIR = "splits"
MESHES_DIR = "meshes"
SDF_DIR = "sdf"
RENDERS_DIR = "renders"
SHAPES_DIR = "shapes"
METADATA_FILE = "rendering_metadata.txt"

SPLITS = ("train", "val", "test")
REQUIRED_CONFIG_KEYS = ("category", "n_views", "image_size")

EXPECTED_LAYOUT = __doc__.split("\n", 2)[2]


def world_dir_name(category: str, config_hash: str) -> str:
    return f"{category}-{config_hash}"


def image_name(view: int) -> str:
    return f"{view:02d}.png"


@dataclass(frozen=True)
class WorldIndex:
    """A built synthetic world: its folder, category, splits, config and per-shape paths."""

    root: Path
    category: str
    splits: dict[str, list[str]]
    config: dict[str, Any] = field(default_factory=dict)

    @property
    def n_views(self) -> int:
        return int(self.config["n_views"])

    @property
    def image_size(self) -> int:
        return int(self.config["image_size"])

    def shape_ids(self, split: str | None = None) -> list[str]:
        """Ids of one split, or of all splits in train/val/test order."""
        if split is None:
            return [sid for s in SPLITS for sid in self.splits.get(s, [])]
        if split not in self.splits:
            raise KeyError(f"unknown split {split!r}; this world has {sorted(self.splits)}")
        return list(self.splits[split])

    def config_path(self) -> Path:
        return self.root / CONFIG_FILE

    def split_path(self, split: str) -> Path:
        return self.root / SPLITS_DIR / f"{split}.json"

    def mesh_path(self, shape_id: str) -> Path:
        return self.root / MESHES_DIR / f"{shape_id}.ply"

    def sdf_path(self, shape_id: str) -> Path:
        return self.root / SDF_DIR / f"{shape_id}.npz"

    def shape_path(self, shape_id: str) -> Path:
        return self.root / SHAPES_DIR / f"{shape_id}.json"

    def render_dir(self, shape_id: str) -> Path:
        return self.root / RENDERS_DIR / shape_id

    def image_path(self, shape_id: str, view: int) -> Path:
        return self.render_dir(shape_id) / image_name(view)

    def view_count(self, shape_id: str) -> int:
        """Views of one shape: n_views, unless config.json lists them per shape (Pix3D: one per photo)."""
        return int(self.config.get("views_per_shape", {}).get(shape_id, self.n_views))

    def image_paths(self, shape_id: str) -> list[Path]:
        return [self.image_path(shape_id, v) for v in range(self.view_count(shape_id))]

    def metadata_path(self, shape_id: str) -> Path:
        return self.render_dir(shape_id) / METADATA_FILE

    def views_path(self, shape_id: str) -> Path:
        return self.render_dir(shape_id) / VIEWS_FILE

    @classmethod
    def load(cls, root: str | Path) -> "WorldIndex":
        """Open a built world folder, checking its layout; raise a descriptive error if it is not one."""
        root = Path(root).expanduser()
        if not root.is_dir():
            raise FileNotFoundError(f"synthetic world folder {root} does not exist.{_layout_hint(root)}")
        config = _read_json(root / CONFIG_FILE, root)
        if not isinstance(config, dict) or any(k not in config for k in REQUIRED_CONFIG_KEYS):
            raise ValueError(f"{root / CONFIG_FILE} lacks the keys {REQUIRED_CONFIG_KEYS}.{_layout_hint(root)}")
        splits = {split: read_split(root, split) for split in SPLITS}
        missing = [d for d in (MESHES_DIR, SDF_DIR, RENDERS_DIR, SHAPES_DIR) if not (root / d).is_dir()]
        if missing:
            raise FileNotFoundError(f"{root} lacks the folders {missing}.{_layout_hint(root)}")
        return cls(root=root, category=str(config["category"]), splits=splits, config=config)


def read_split(root: str | Path, split: str) -> list[str]:
    """Shape ids of one split of a world (its splits/<split>.json), checked: the one reader of split files."""
    root = Path(root)
    path = root / SPLITS_DIR / f"{split}.json"
    ids = _read_json(path, root)
    if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
        raise ValueError(
            f"{path} must hold a JSON list of shape id strings; rebuild the world with SyntheticWorld(...).build()"
        )
    return ids


def _read_json(path: Path, root: Path) -> Any:
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: {root} is not a built synthetic world.{_layout_hint(root)}")
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise ValueError(f"{path} is unreadable ({err}); rebuild the world with SyntheticWorld(...).build()") from err


def _layout_hint(root: Path) -> str:
    """Expected layout, plus the world folders found under `root` if it is their parent."""
    hint = f"\nExpected a folder built by ushape.data.world.SyntheticWorld(...).build():\n{EXPECTED_LAYOUT}"
    if root.is_dir():
        worlds = sorted(p.name for p in root.iterdir() if (p / CONFIG_FILE).is_file())
        if worlds:
            hint = f"\n{root} holds the world folders {worlds}: point at one of them." + hint
    return hint
