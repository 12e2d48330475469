"""The views reconstruct.py refines on, from its input images: each one's camera, mask and depth where known.

Cameras, in this order of precedence:
  - a camera file the user passes: an .npz laid out like the world's views.npz, one entry per input
    image in input order: K [V, 3, 3] (for each image's own pixel size), world_to_cam [V, 4, 4], and
    optionally masks [V, H, W] and depth [V, H, W] (camera-frame z, 0 = no return); where the object's pose
    is estimated (--pose estimate), world_to_cam may be left out (an RGB-D frame: K and depth, in any units);
  - a render of our world (renders/<id>/NN.png with views.npz beside it): its own camera, mask and depth;
  - an R2N2 render (rendering/NN.png with rendering_metadata.txt beside it): the camera of its metadata row,
    with the object placed in R2N2's frame as the model's training shapes typically are (`typical_r2n2_frame`).
Masks: the mask files passed (one per image, white = object), else the camera file's or views.npz's stored
masks, else the image's alpha. An image with no camera is returned as None: the refinement skips it, saying so.
"""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from ushape.data.augment import read_image
from ushape.data.cameras import intrinsics, metadata_to_cameras, parse_metadata
from ushape.data.layout import VIEWS_FILE, WorldIndex
from ushape.data.real.shapenet_rendering import METADATA_FILE
from ushape.errors import InputError, MissingInputError
from ushape.refinement.joint import PLACEHOLDER_CAMERA, PoseGroups
from ushape.refinement.views import FULL_MASK, ObservedView, camera_problem

log = logging.getLogger(__name__)
R2N2Frame = tuple[np.ndarray, float]  # (r2n2_centre [3], r2n2_scale): R2N2's frame in the model's (data.cameras)


def image_mask(path: str | Path, from_alpha: bool = True) -> torch.Tensor:
    """[H, W] float mask of an image: its alpha (from_alpha), else its grey level (a mask file), as 0 / 1."""
    rgba = read_image(path)
    level = rgba[..., 3] if from_alpha else rgba[..., :3].mean(-1)
    return torch.as_tensor(level > 0.5).float()


def image_size(path: str | Path) -> tuple[int, int]:
    """(H, W) of an image file, after its EXIF orientation (as `read_image` turns it)."""
    return tuple(read_image(path).shape[:2])


def load_camera_file(cameras: str | Path, pose_unknown: bool = False) -> dict[str, np.ndarray]:
    """The arrays of a views.npz-like camera file; an InputError naming the file when it is not one. With
    pose_unknown (the object's pose is estimated), world_to_cam may be left out: an RGB-D frame's K and depth,
    say; each view then carries a placeholder camera the estimate replaces."""
    path = Path(cameras)
    if not path.is_file():
        raise MissingInputError(f"camera file {path} does not exist")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        raise InputError(
            f"camera file {path} is not a readable .npz archive ({type(err).__name__}): save it with "
            "numpy.savez(path, K=..., world_to_cam=...)"
        ) from err
    if "K" in arrays and "world_to_cam" not in arrays and pose_unknown:
        arrays["world_to_cam"] = np.repeat(PLACEHOLDER_CAMERA[None], len(arrays["K"]), axis=0)
    if "K" in arrays and "world_to_cam" not in arrays:
        raise InputError(
            f"camera file {path} has K but no world_to_cam [V, 4, 4]: where the cameras stood is unknown, so pass "
            "--pose estimate to estimate the object's pose with its shape, or add world_to_cam"
        )
    if "K" not in arrays or "world_to_cam" not in arrays:
        raise InputError(f"camera file {path} needs arrays K [V, 3, 3] and world_to_cam [V, 4, 4]")
    for key, shape in (("K", (3, 3)), ("world_to_cam", (4, 4))):
        value = arrays[key]
        if value.ndim != 3 or value.shape[1:] != shape:
            raise InputError(f"camera file {path}: {key} must be [V, {shape[0]}, {shape[1]}], got {value.shape}")
    return arrays


def camera_file_views(
    cameras: str | Path, images: Sequence[Path], masks: Sequence[Path] | None, pose_unknown: bool = False
) -> list[ObservedView | None]:
    """One ObservedView per image from a views.npz-like camera file (see the module docstring; pose_unknown:
    `load_camera_file`'s)."""
    data = load_camera_file(cameras, pose_unknown)
    if len(data["K"]) != len(images):
        raise InputError(f"camera file {cameras} has {len(data['K'])} cameras for {len(images)} input images")
    views = []
    for i, image in enumerate(images):
        where = f"camera file {cameras}, view {i} ({Path(image).name})"
        if masks is not None:  # the masks passed win over stored ones, as for a render's views.npz
            mask, mask_source = image_mask(masks[i], from_alpha=False), str(masks[i])
        elif "masks" in data:
            mask, mask_source = torch.as_tensor(data["masks"][i]).float(), f"{cameras}'s masks[{i}]"
        else:
            mask, mask_source = image_mask(image), f"{Path(image).name}'s alpha"
        depth = torch.as_tensor(data["depth"][i]).float() if "depth" in data else None
        view = ObservedView(data["K"][i].astype(np.float64), data["world_to_cam"][i].astype(np.float64), mask, depth)
        views.append(checked_view(view, image, where, mask_source))
    return views


def checked_view(view: ObservedView, image: Path, where: str, mask_source: str) -> ObservedView:
    """The view, after checking its camera and that its mask (and depth) are the size of its image: an InputError
    naming `where` otherwise."""
    hw = image_size(image)
    if tuple(view.mask.shape) != hw:
        raise InputError(
            f"{where}: the mask ({mask_source}) is {view.mask.shape[1]}x{view.mask.shape[0]} pixels, the image "
            f"{hw[1]}x{hw[0]}: pass a mask of the image's size"
        )
    if view.depth is not None and tuple(view.depth.shape) != hw:
        raise InputError(
            f"{where}: the depth map is {view.depth.shape[1]}x{view.depth.shape[0]} pixels, the image {hw[1]}x{hw[0]}"
        )
    problem = camera_problem(view.K, view.world_to_cam, hw)
    if problem is not None:
        raise InputError(f"{where}: {problem}")
    return view


def render_view(views_npz: Path, index: int, image: Path, mask: Path | None) -> ObservedView:
    """A render's view from its views.npz; the mask file passed, else the stored mask, else the image's alpha."""
    data = load_camera_file(views_npz)
    where = f"{views_npz}, view {index} ({Path(image).name})"
    if not 0 <= index < len(data["K"]):
        raise InputError(f"{where}: the file holds views 0..{len(data['K']) - 1} only")
    K, w2c = data["K"][index].astype(np.float64), data["world_to_cam"][index].astype(np.float64)
    depth = torch.as_tensor(data["depth"][index]).float() if "depth" in data else None
    if mask is not None:
        found, source = image_mask(mask, from_alpha=False), str(mask)
    elif "masks" in data:
        found, source = torch.as_tensor(data["masks"][index]).float(), f"{views_npz.name}'s masks[{index}]"
    else:
        found, source = image_mask(image), f"{Path(image).name}'s alpha"
    return checked_view(ObservedView(K, w2c, found, depth), image, where, source)


def typical_r2n2_frame(world: WorldIndex, split: str = "train", limit: int = 200) -> R2N2Frame | None:
    """Where R2N2's frame sits in a world's frame for a typical shape: the median (r2n2_centre [3], r2n2_scale)
    of the first `limit` shapes' views.npz; None where the world stores none. R2N2's frame is each model's
    own (box centre, unit diagonal) and the world rescales each shape to the unit sphere, so the scale varies
    by shape (chairs: 5th-95th percentile of r2n2_scale within -11 % / +3 % of the median): cameras placed
    with the typical frame see an unseen object up to that much too large or small."""
    centres, scales = [], []
    for shape_id in world.shape_ids(split)[:limit]:
        try:
            with np.load(world.views_path(shape_id)) as views:
                if "r2n2_centre" in views.files:
                    centres.append(views["r2n2_centre"].astype(np.float64))
                    scales.append(float(views["r2n2_scale"]))
        except (OSError, ValueError, zipfile.BadZipFile):
            continue
    if not scales:
        return None
    return np.median(np.stack(centres), axis=0), float(np.median(scales))


def r2n2_render_view(image: Path, mask: Path | None, frame: R2N2Frame) -> ObservedView:
    """An R2N2 render's view (rendering/NN.png with rendering_metadata.txt beside it): its camera from its row of
    the metadata, the object placed in R2N2's frame by `frame`; its mask the mask file, else its alpha."""
    metadata = Path(image).parent / METADATA_FILE
    where = f"{metadata}, view {int(Path(image).stem)} ({Path(image).name})"
    try:
        rows = parse_metadata(metadata.read_text())
    except (OSError, ValueError) as err:
        raise InputError(f"{where}: cannot read the metadata ({err})") from err
    index = int(Path(image).stem)
    if index >= len(rows):
        raise InputError(f"{where}: the metadata has {len(rows)} rows, none for view {index}")
    hw = image_size(image)
    K, w2c = metadata_to_cameras(rows[index : index + 1], hw, r2n2_centre=frame[0], r2n2_scale=frame[1])
    found, source = (
        (image_mask(image), f"{Path(image).name}'s alpha") if mask is None else (image_mask(mask, False), str(mask))
    )
    return checked_view(ObservedView(K[0], w2c[0], found, None), image, where, source)


def input_views(
    images: Sequence[Path],
    cameras: str | Path | None = None,
    masks: Sequence[Path] | None = None,
    r2n2_frame: R2N2Frame | None = None,
    pose_unknown: bool = False,
) -> list[ObservedView | None]:
    """Per input image its ObservedView, or None where no camera is known (a photo without a camera file).

    r2n2_frame: where R2N2's frame sits in the model's (`typical_r2n2_frame`), for R2N2 renders.
    pose_unknown: the object's pose is estimated, so a camera file may hold K (and depth, masks) alone.
    """
    if masks is not None and len(masks) != len(images):
        raise InputError(f"{len(masks)} mask files for {len(images)} images: pass one mask per image, in order")
    if cameras is not None:
        return camera_file_views(cameras, images, masks, pose_unknown)
    views = []
    for i, image in enumerate(images):
        folder, numbered, mask = Path(image).parent, Path(image).stem.isdigit(), None if masks is None else masks[i]
        if numbered and (folder / VIEWS_FILE).is_file():
            views.append(render_view(folder / VIEWS_FILE, int(Path(image).stem), image, mask))
        elif numbered and (folder / METADATA_FILE).is_file() and r2n2_frame is not None:
            views.append(r2n2_render_view(image, mask, r2n2_frame))
        else:
            why = "the model knows no R2N2 frame" if numbered and (folder / METADATA_FILE).is_file() else "no camera"
            log.warning("%s: %s (not a render of the world, no --cameras file)", image, why)
            views.append(None)
    return views


def unposed_views(
    images: Sequence[Path],
    views: Sequence[ObservedView | None],
    masks: Sequence[Path] | None,
    fov_deg: float,
) -> list[ObservedView]:
    """Per image the view the pose estimation reads: its known K and mask where it has a camera (the pose is
    estimated instead), else K from its size and `fov_deg` and its mask (the mask file, else its alpha).
    world_to_cam is a placeholder the estimate replaces."""
    out = []
    for i, image in enumerate(images):
        if views[i] is not None:
            out.append(views[i])
            continue
        mask = image_mask(image) if masks is None else image_mask(masks[i], False)
        if float(mask.mean()) >= FULL_MASK:
            raise InputError(
                f"{image}: no mask and no alpha channel to tell the object from the background, so its pose cannot "
                "be estimated: pass --masks MASK.png (white = object), one per image"
            )
        K = intrinsics(fov_deg, tuple(mask.shape))
        out.append(ObservedView(K=K, world_to_cam=PLACEHOLDER_CAMERA, mask=mask))
    return out


def relative_pose_groups(path: str | Path, n_views: int) -> PoseGroups:
    """One shared object pose for views whose cameras are known up to one unknown frame: an npz with world_to_cam
    [V, 4, 4] (rigid) in input order, in any frame (only the motion between them is used)."""
    path = Path(path)
    if not path.is_file():
        raise MissingInputError(f"relative poses file {path} does not exist")
    try:
        with np.load(path, allow_pickle=False) as data:
            w2c = np.asarray(data["world_to_cam"], dtype=np.float64)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as err:
        raise InputError(
            f"relative poses {path} is not an .npz with world_to_cam [V, 4, 4] ({type(err).__name__}): save it with "
            "numpy.savez(path, world_to_cam=...)"
        ) from err
    if w2c.shape != (n_views, 4, 4):
        raise InputError(
            f"relative poses {path}: world_to_cam must be [{n_views}, 4, 4] (one per input image), got {w2c.shape}"
        )
    for i, m in enumerate(w2c):
        r = m[:3, :3]
        if not (np.isfinite(m).all() and np.allclose(r @ r.T, np.eye(3), atol=1e-3) and np.linalg.det(r) > 0):
            raise InputError(f"relative poses {path}: world_to_cam[{i}] is not a rigid motion")
    return PoseGroups.from_cameras(list(w2c))
