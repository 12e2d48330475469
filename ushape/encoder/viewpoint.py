"""Where the camera stood: a small head on the frozen encoder's features that classifies the camera's azimuth about
the object's vertical.

A silhouette alone leaves the pose of a chair or a table ambiguous (front and back, left and right outline
alike), but the image's appearance does not: on the 100 val chairs of the real-shape model, a 2-layer head on
the frozen features puts the azimuth within 15 degrees of the truth for 92 % of the views (docs/pose.md). The
pose-and-shape refinement (`ushape.refinement.joint`) starts its hypotheses from this distribution and adds
-log p(hypothesis) to each one's energy, so the masks decide between the azimuths the image allows.

The azimuth is the camera centre's, in the object frame, as `ushape.data.cameras.orbit_position` places it:
c = d (cos el cos az, sin el, cos el sin az). `bins` classes of 360 / bins degrees, centred on 0, 15, 30, ...
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor, nn


def camera_azimuth_elevation(world_to_cam: np.ndarray) -> tuple[float, float]:
    """(azimuth in [0, 360), elevation) in degrees of a camera [4, 4] about the object's origin, y up."""
    w2c = np.asarray(world_to_cam, dtype=np.float64)
    centre = -w2c[:3, :3].T @ w2c[:3, 3]
    azimuth = math.degrees(math.atan2(centre[2], centre[0])) % 360.0
    return azimuth, math.degrees(math.asin(centre[1] / np.linalg.norm(centre)))


def angular_difference(a: Tensor, b: Tensor) -> Tensor:  # degrees, any shapes that broadcast -> [0, 180]
    d = (a - b).abs() % 360.0
    return torch.minimum(d, 360.0 - d)


class ViewpointHead(nn.Module):
    """features [B, F] (the frozen backbone's) -> azimuth logits [B, bins]; the features standardised by the
    statistics of its training set."""

    def __init__(self, n_features: int, bins: int = 24, hidden: int = 256, dropout: float = 0.2) -> None:
        super().__init__()
        self.config = {"n_features": n_features, "bins": bins, "hidden": hidden, "dropout": dropout}
        self.register_buffer("feature_mean", torch.zeros(n_features))
        self.register_buffer("feature_std", torch.ones(n_features))
        self.net = nn.Sequential(
            nn.Dropout(dropout), nn.Linear(n_features, hidden), nn.ReLU(), nn.Dropout(dropout), nn.Linear(hidden, bins)
        )

    @property
    def bins(self) -> int:
        return int(self.config["bins"])

    @property
    def bin_centres(self) -> Tensor:  # [bins] degrees
        return torch.arange(self.bins, dtype=torch.float64) * (360.0 / self.bins)

    def forward(self, features: Tensor) -> Tensor:
        return self.net((features - self.feature_mean) / self.feature_std)

    @torch.no_grad()
    def log_probs(self, features: Tensor) -> Tensor:  # [B, bins]
        self.eval()
        return self(features.float()).log_softmax(-1).double()

    def labels(self, azimuths: Tensor) -> Tensor:  # degrees [N] -> nearest bin [N]
        return (azimuths / (360.0 / self.bins)).round().long() % self.bins


def fit_viewpoint_head(
    features: Tensor,  # [N, F]
    azimuths: Tensor,  # [N] degrees
    bins: int = 24,
    epochs: int = 30,
    seed: int = 0,
    batch_size: int = 256,
) -> ViewpointHead:
    """A ViewpointHead trained by label-smoothed cross entropy (AdamW, lr 1e-3, weight decay 1e-2)."""
    if features.ndim != 2 or features.shape[0] != azimuths.shape[0] or features.shape[0] < bins:
        raise ValueError(f"need features [N, F] and azimuths [N] with N >= {bins}, got {tuple(features.shape)}, "
                         f"{tuple(azimuths.shape)}")  # fmt: skip
    generator = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    head = ViewpointHead(features.shape[1], bins)
    head.feature_mean.copy_(features.mean(0))
    head.feature_std.copy_(features.std(0).clamp_min(1e-6))
    target = head.labels(azimuths.double())
    optimiser = torch.optim.AdamW(head.parameters(), lr=1e-3, weight_decay=1e-2)
    head.train()
    for _ in range(epochs):
        order = torch.randperm(features.shape[0], generator=generator)
        for start in range(0, features.shape[0], batch_size):
            batch = order[start : start + batch_size]
            loss = nn.functional.cross_entropy(head(features[batch].float()), target[batch], label_smoothing=0.1)
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
    head.eval()
    return head


def viewpoint_scores(head: ViewpointHead, features: Tensor, azimuths: Tensor) -> dict[str, float]:
    """The head's azimuth error on held-out views: median (degrees), within 15 and 30 degrees, past 150 (a front /
    back flip), and the truth within 15 degrees of one of its 3 most likely bins."""
    logp = head.log_probs(features)
    centres = head.bin_centres
    error = angular_difference(centres[logp.argmax(-1)], azimuths.double())
    top3 = angular_difference(centres[logp.topk(3, dim=-1).indices], azimuths.double()[:, None]).min(-1).values
    return {
        "views": int(features.shape[0]),
        "median_error_deg": float(error.median()),
        "within_15": float((error <= 15).double().mean()),
        "within_30": float((error <= 30).double().mean()),
        "flipped": float((error > 150).double().mean()),
        "top3_within_15": float((top3 <= 15).double().mean()),
    }


def save_viewpoint_head(head: ViewpointHead, path, scores: dict | None = None) -> None:
    """The head, its layers' weights in fp16 (half the size a shipped model carries; the standardisation stays fp32),
    with its held-out scores."""
    from ushape import atomic

    state = {k: v.half() if k.startswith("net.") else v for k, v in head.state_dict().items()}
    atomic.torch_save({"config": head.config, "state_dict": state, "scores": scores or {}}, path)


def load_viewpoint_head(path) -> ViewpointHead:
    blob = torch.load(path, map_location="cpu", weights_only=False)
    head = ViewpointHead(**blob["config"])
    head.load_state_dict({k: v.float() for k, v in blob["state_dict"].items()})
    return head.eval()
