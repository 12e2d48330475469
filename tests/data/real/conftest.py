"""Fixtures for the real-dataset tests: tiny meshes written as OBJ files in the official layouts."""

import os
from pathlib import Path

import numpy as np
import pytest
import trimesh

REAL_SAMPLE = Path(os.path.dirname(os.path.abspath(__file__))).parents[3] / "shared" / "data" / "real_sample"
CHAIRS = "03001627"


def write_obj(path: Path, mesh: trimesh.Trimesh) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(trimesh.exchange.obj.export_obj(mesh, include_texture=False))
    return path


def box(extents=(0.4, 0.8, 0.3), centre=(0.1, 0.2, -0.1)) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


@pytest.fixture
def make_box():
    return box


@pytest.fixture
def save_obj():
    return write_obj


@pytest.fixture
def shapenet_tree(tmp_path):
    """A ShapeNet tree maker: (layout, ids) -> root holding one box per model id."""

    def make(layout: str, ids, synset: str = CHAIRS) -> Path:
        root = tmp_path / f"ShapeNetCore.{layout}"
        rel = "model.obj" if layout == "v1" else "models/model_normalized.obj"
        for i, model_id in enumerate(ids):
            write_obj(root / synset / model_id / rel, box(extents=(0.3 + 0.05 * i, 0.6, 0.35)))
        return root

    return make


def _require(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"real sample data not present at {path}")
    return path


@pytest.fixture
def shapenet_sample() -> Path:
    return _require(REAL_SAMPLE / "ShapeNetCore.v2")


@pytest.fixture
def pix3d_sample() -> Path:
    return _require(REAL_SAMPLE / "pix3d")


@pytest.fixture
def rng():
    return np.random.default_rng(0)
