"""Write a reconstructed mesh with its per-vertex SDF standard deviation: PLY, GLB and a colour bar.

The std is stored twice: raw, as a float vertex attribute (PLY property `std`; GLB primitive
attribute `_STD`, glTF's prefix for application-specific data), and as vertex colours from a
matplotlib colormap over the range [0, std_max]. std_max is the caller's (to compare
reconstructions on one scale) or else the 99th percentile of this mesh's stds, so a few
extreme vertices do not wash out the rest; values above it get the colormap's top colour.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from ushape import atomic  # noqa: E402

PLY_STD = "std"
GLB_STD = "_STD"
DEFAULT_CMAP = "inferno"
AUTO_PERCENTILE = 99.0


def colour_range(std: np.ndarray, std_max: float | None = None) -> float:
    """The top of the colour scale: std_max if given, else the 99th percentile of std (> 0)."""
    if std_max is not None:
        if not std_max > 0:
            raise ValueError(f"std_max must be > 0, got {std_max}")
        return float(std_max)
    top = float(np.percentile(std, AUTO_PERCENTILE)) if len(std) else 0.0
    return top if top > 0 else 1.0


def std_colours(std: np.ndarray, std_max: float, cmap: str = DEFAULT_CMAP) -> np.ndarray:
    """RGBA uint8 [V, 4] of std [V] through a matplotlib colormap over [0, std_max]."""
    normalised = np.clip(np.asarray(std, np.float64) / std_max, 0.0, 1.0)
    return (plt.get_cmap(cmap)(normalised) * 255).round().astype(np.uint8)


def coloured_mesh(mesh: trimesh.Trimesh, std: np.ndarray, std_max: float, cmap: str = DEFAULT_CMAP) -> trimesh.Trimesh:
    """A copy of mesh with std-coloured vertices (std [V] in the mesh's vertex order)."""
    std = np.asarray(std, np.float32).reshape(-1)
    if len(std) != len(mesh.vertices):
        raise ValueError(f"{len(std)} std values for a mesh of {len(mesh.vertices)} vertices")
    return trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_colors=std_colours(std, std_max, cmap), process=False)


def write_mesh_files(
    mesh: trimesh.Trimesh,
    std: np.ndarray,  # [V]
    out_dir: str | Path,
    stem: str = "mesh",
    std_max: float | None = None,
    cmap: str = DEFAULT_CMAP,
) -> dict[str, str | float]:
    """<stem>.ply, <stem>.glb and <stem>_colourbar.png; returns their paths and the colour range."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    std = np.asarray(std, np.float32).reshape(-1)
    top = colour_range(std, std_max)
    coloured = coloured_mesh(mesh, std, top, cmap)
    paths = {
        "ply": out_dir / f"{stem}.ply",
        "glb": out_dir / f"{stem}.glb",
        "colour_bar": out_dir / f"{stem}_colourbar.png",
    }
    coloured.vertex_attributes[PLY_STD] = std
    atomic.write_bytes(paths["ply"], coloured.export(file_type="ply"))
    del coloured.vertex_attributes[PLY_STD]
    coloured.vertex_attributes[GLB_STD] = std
    atomic.write_bytes(paths["glb"], coloured.export(file_type="glb"))
    write_colour_bar(paths["colour_bar"], top, cmap)
    return {**{k: str(v) for k, v in paths.items()}, "std_max": top, "cmap": cmap}


def write_colour_bar(path: str | Path, std_max: float, cmap: str = DEFAULT_CMAP, label: str = "SDF std") -> None:
    """A horizontal colour bar PNG for [0, std_max]."""
    fig, ax = plt.subplots(figsize=(4.0, 0.9), dpi=120)
    mappable = plt.cm.ScalarMappable(norm=matplotlib.colors.Normalize(0.0, std_max), cmap=cmap)
    fig.colorbar(mappable, cax=ax, orientation="horizontal", label=label)
    fig.subplots_adjust(left=0.05, right=0.95, bottom=0.55, top=0.9)
    with atomic.atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)


def read_ply_std(path: str | Path) -> np.ndarray:
    """The `std` vertex property [V] of a PLY written by `write_mesh_files`."""
    mesh = trimesh.load(path, process=False)
    return np.asarray(mesh.metadata["_ply_raw"]["vertex"]["data"][PLY_STD])


def read_glb_std(path: str | Path) -> np.ndarray:
    """The `_STD` vertex attribute [V] of a GLB written by `write_mesh_files`."""
    scene = trimesh.load(path, process=False)
    (mesh,) = scene.geometry.values()
    return np.asarray(mesh.vertex_attributes[GLB_STD]).reshape(-1)
