"""Where the camera may look next: candidate poses around one object, and the image each would give.

Two sources of candidates:
- orbit: the protocol's orbit (`ushape.data.cameras`): n_azimuth azimuths over [0, 360) times elevations
  spread over the world's range (R2N2: 25-30 degrees), at one distance ratio, framed on the object as the
  world framed its own renders (its R2N2 centre and scale). A view is acquired by rendering the true shape
  from that pose with the world's own renderer, part colours and lighting, so it looks like the views the
  encoder was trained on. Needs a synthetic world this version can rebuild (the shape's parts give its colours).
- recorded: the world's own views with their cameras (views.npz): for real data, where no new image can be
  rendered, the next view is picked among those that exist.

The pose of a candidate is for choosing it only; what is fused is its image (the paper's fusion is pose-free).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import torch
import trimesh
from torch import Tensor

from ushape.data.augment import load_rgba, premultiply
from ushape.data.cameras import (
    DISTANCE_RATIO_RANGE,
    ELEVATION_RANGE,
    R2N2_FOV_DEG,
    camera_centre,
    metadata_to_cameras,
)
from ushape.data.layout import WorldIndex
from ushape.data.rendering import RayCaster, render_mesh
from ushape.data.shading import part_colour_fn
from ushape.data.world import SyntheticWorld
from ushape.refinement.views import ObservedView, world_views

SOURCES = ("auto", "orbit", "recorded")


@dataclass(frozen=True)
class CandidateViews:
    """C camera poses around one object and, on request, the premultiplied RGBA image [4, H, W] of each."""

    shape_id: str
    K: np.ndarray  # [C, 3, 3] pixels, principal point at the image centre
    world_to_cam: np.ndarray  # [C, 4, 4] OpenCV axes
    target: np.ndarray  # [3] the point the cameras look at (the object's centre)
    source: str  # "orbit" | "recorded"
    acquire: Callable[[int], Tensor] = field(repr=False)
    # what the view shows as the refinement reads it (camera, mask, depth); None: the source has no masks
    observation: Callable[[int], ObservedView] | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.K)

    @property
    def centres(self) -> np.ndarray:
        """Camera centres [C, 3] in the object's frame."""
        return camera_centre(self.world_to_cam)

    @property
    def directions(self) -> np.ndarray:
        """[C, 3] from the target (the object's centre) to each camera."""
        return self.centres - self.target

    @property
    def image_hw(self) -> np.ndarray:
        """(H, W) [C, 2] of each candidate's image, from its principal point (the image centre)."""
        return np.round(2.0 * self.K[:, [1, 0], 2]).astype(np.int64)

    def azimuth_elevation(self) -> np.ndarray:
        """[C, 2] degrees of each camera about the target in the object's frame, azimuth from +x towards +z
        (R2N2's convention in its own axes; a ShapeNetCore.v2 world's frame is turned 90 degrees from it)."""
        d = self.directions
        azimuth = np.degrees(np.arctan2(d[:, 2], d[:, 0])) % 360.0
        elevation = np.degrees(np.arcsin(d[:, 1] / np.linalg.norm(d, axis=1)))
        return np.stack([azimuth, elevation], axis=1)

    def image(self, index: int) -> Tensor:
        if not 0 <= index < len(self):
            raise IndexError(f"candidate {index} of {len(self)}")
        return self.acquire(index)

    def observed(self, index: int) -> ObservedView:
        """The candidate's camera, mask and depth (full image): what a refinement on it compares with."""
        if not 0 <= index < len(self):
            raise IndexError(f"candidate {index} of {len(self)}")
        if self.observation is None:
            raise ValueError(f"the {self.source} candidates of {self.shape_id} have no masks to refine on")
        return self.observation(index)


def orbit_rows(
    n_azimuth: int, elevations: Sequence[float], distance_ratio: float = float(np.mean(DISTANCE_RATIO_RANGE))
) -> np.ndarray:
    """R2N2 metadata rows [C, 5] (az el inplane dist_ratio fov): every azimuth k * 360 / n_azimuth at each elevation."""
    if n_azimuth < 1 or not len(elevations):
        raise ValueError(f"need n_azimuth >= 1 and at least one elevation, got {n_azimuth} and {list(elevations)}")
    if distance_ratio <= 0:
        raise ValueError(f"distance_ratio must be > 0, got {distance_ratio}")
    return np.array(
        [[360.0 * k / n_azimuth, el, 0.0, distance_ratio, R2N2_FOV_DEG] for el in elevations for k in range(n_azimuth)]
    )


def spread_elevations(n_elevation: int, span: Sequence[float] = ELEVATION_RANGE) -> list[float]:
    """n_elevation elevations evenly over the range (one: its middle)."""
    if n_elevation < 1:
        raise ValueError(f"n_elevation must be >= 1, got {n_elevation}")
    low, high = span
    if n_elevation == 1:
        return [(low + high) / 2.0]
    return [float(e) for e in np.linspace(low, high, n_elevation)]


def orbit_views(
    world: WorldIndex,
    shape_id: str,
    n_azimuth: int = 12,
    n_elevation: int = 2,
    distance_ratio: float = float(np.mean(DISTANCE_RATIO_RANGE)),
    rows: np.ndarray | None = None,
) -> CandidateViews:
    """Candidates on the protocol's orbit, acquired by rendering the true shape (cached per candidate).

    rows: R2N2 metadata rows [C, 5] to use instead of the orbit grid (e.g. the world's own, to re-render its views).
    """
    shape = synthetic_shape(world, shape_id)
    with np.load(world.views_path(shape_id)) as views:
        if "r2n2_centre" not in views:
            raise ValueError(f"{world.views_path(shape_id)} has no r2n2_centre/r2n2_scale: not a synthetic render")
        centre, scale = views["r2n2_centre"].astype(np.float64), float(views["r2n2_scale"])
    if rows is None:
        rows = orbit_rows(n_azimuth, spread_elevations(n_elevation), distance_ratio)
    Ks, world_to_cams = metadata_to_cameras(rows, world.image_size, r2n2_centre=centre, r2n2_scale=scale)
    mesh = trimesh.load(world.mesh_path(shape_id), process=False, force="mesh")
    caster, colour, rendered = RayCaster(mesh), part_colour_fn(shape), {}

    def render(index: int) -> dict:
        if index not in rendered:
            rendered[index] = render_mesh(caster, Ks[index], world_to_cams[index], world.image_size, colour)
        return rendered[index]

    def acquire(index: int) -> Tensor:
        return premultiply(render(index)["rgba"].astype(np.float32) / 255.0)

    def observation(index: int) -> ObservedView:
        view = render(index)
        mask, depth = torch.as_tensor(view["mask"]).float(), torch.as_tensor(view["depth"]).float()
        return ObservedView(Ks[index], world_to_cams[index], mask, depth)

    return CandidateViews(shape_id, Ks, world_to_cams, centre, "orbit", acquire, observation)


def recorded_views(world: WorldIndex, shape_id: str) -> CandidateViews:
    """The world's own views of the shape as candidates (their cameras from views.npz)."""
    path = world.views_path(shape_id)
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: the views of {shape_id} have no cameras to choose among")
    with np.load(path) as views:
        Ks, world_to_cams = views["K"].astype(np.float64), views["world_to_cam"].astype(np.float64)
        target = views["r2n2_centre"].astype(np.float64) if "r2n2_centre" in views else np.zeros(3)
        has_masks = "masks" in views.files
    n = min(len(Ks), world.view_count(shape_id))

    def observation(index: int) -> ObservedView:
        (view,) = world_views(path, [index])
        return view

    return CandidateViews(
        shape_id,
        Ks[:n],
        world_to_cams[:n],
        target,
        "recorded",
        lambda i: load_rgba(world.image_path(shape_id, i)),
        observation if has_masks else None,
    )


def candidate_views(
    world: WorldIndex, shape_id: str, source: str = "auto", n_azimuth: int = 12, n_elevation: int = 2
) -> CandidateViews:
    """Candidates from `source`: orbit, recorded, or auto (orbit where the world can render new views).
    n_azimuth and n_elevation size the orbit; recorded views are what they are."""
    if source not in SOURCES:
        raise ValueError(f"candidate source must be one of {SOURCES}, got {source!r}")
    if source == "auto":
        source = "orbit" if can_render(world) else "recorded"
    if source == "orbit":
        return orbit_views(world, shape_id, n_azimuth, n_elevation)
    return recorded_views(world, shape_id)


def can_render(world: WorldIndex) -> bool:
    """Whether new views of the world's shapes can be rendered here (a synthetic world this version rebuilds)."""
    return SyntheticWorld.from_index(world) is not None


def synthetic_shape(world: WorldIndex, shape_id: str):
    """The procedural shape behind one of a synthetic world's meshes, regenerated from its seed."""
    builder = SyntheticWorld.from_index(world)
    if builder is None:
        raise ValueError(
            f"{world.root} is not a synthetic world this version can rebuild, so no new view can be rendered: "
            "choose among its own views (candidates=recorded)"
        )
    record = json.loads(world.shape_path(shape_id).read_text())
    shape = builder.factory(world.category, int(record["seed"]))
    if shape.shape_id != shape_id:
        raise ValueError(f"seed {record['seed']} regenerates {shape.shape_id}, not {shape_id}: the world is stale")
    return shape
