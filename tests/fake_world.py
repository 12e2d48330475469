"""The one writer of fake worlds in the tests: every file lands where ushape.data.layout says it lives."""

from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from ushape import atomic
from ushape.data.layout import CONFIG_FILE, MESHES_DIR, RENDERS_DIR, SDF_DIR, SHAPES_DIR, WorldIndex


def new_world(root, splits: dict[str, list[str]], config: dict | None = None) -> WorldIndex:
    """A world folder with its splits (and config.json when given) written and its folders made."""
    root = Path(root)
    world = WorldIndex(root=root, category=(config or {}).get("category", "fake"), splits=splits, config=config or {})
    for folder in (MESHES_DIR, SDF_DIR, RENDERS_DIR, SHAPES_DIR):
        (root / folder).mkdir(parents=True, exist_ok=True)
    if config is not None:
        atomic.write_json(root / CONFIG_FILE, config)
    for split, ids in splits.items():
        atomic.write_json(world.split_path(split), list(ids))
    return world


def write_views(world: WorldIndex, shape_id: str, images: list[np.ndarray], **views: np.ndarray) -> None:
    """RGBA uint8 images [H, W, 4] as the shape's renders, and `views` (K, world_to_cam, ...) as views.npz."""
    world.render_dir(shape_id).mkdir(parents=True, exist_ok=True)
    for view, image in enumerate(images):
        Image.fromarray(np.asarray(image, dtype=np.uint8), "RGBA").save(world.image_path(shape_id, view))
    if views:
        np.savez(world.views_path(shape_id), **views)


def write_sdf(world: WorldIndex, shape_id: str, samples: np.ndarray) -> None:
    """DeepSDF samples [N, 4] (xyz, sdf) as the shape's sdf/<id>.npz, split into pos and neg."""
    samples = np.asarray(samples, dtype=np.float32)
    atomic.save_npz(world.sdf_path(shape_id), pos=samples[samples[:, 3] >= 0], neg=samples[samples[:, 3] < 0])


def write_mesh(world: WorldIndex, shape_id: str, mesh: trimesh.Trimesh) -> None:
    atomic.write_bytes(world.mesh_path(shape_id), mesh.export(file_type="ply"))
