"""The object's pose as part of the refinement's state: a similarity transform and its small perturbations.

A pose T = (R, t, s) maps the object's (the decoder's) frame into a reference camera's frame:
x_ref = s R x_obj + t. A view with a known motion from that reference (cam_from_ref, rigid) then sees the
object through the rigid camera in object units

    world_to_cam = [R_c R | (R_c t + t_c) / s]     (`object_camera`)

(dividing the camera frame by s changes no pixel), so the silhouette machinery of `observation` runs
unchanged on it. One view alone cannot tell a large object far away from a small one near: the scale
only enters with a baseline between views (`scale_observable`).

Steps perturb T on the object's side, T' = T o delta, with delta(y) = e^sigma Exp(omega) y + v and the
state xi = (omega [3] (radians, about the object's origin), v [3] (object units), sigma (log scale)).
For a point fixed in the camera, its object-frame position moves as x' = delta^-1(x) ~ x - omega x x - v -
sigma x, so an SDF value s(x) changes by (`point_jacobian`)

    ds/domega = g x x,   ds/dv = -g,   ds/dsigma = -g . x          (g = ds/dx at x).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

ROTATION, TRANSLATION, SCALE = slice(0, 3), slice(3, 6), slice(6, 7)


def skew(w: np.ndarray) -> np.ndarray:  # [3] -> [3, 3]
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def exp_so3(w: np.ndarray) -> np.ndarray:  # rotation vector [3] -> R [3, 3] (Rodrigues)
    w = np.asarray(w, dtype=np.float64)
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3) + skew(w)
    k = skew(w / angle)
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def log_so3(R: np.ndarray) -> np.ndarray:  # R [3, 3] -> rotation vector [3], angle in [0, pi]
    R = np.asarray(R, dtype=np.float64)
    cos = min(1.0, max(-1.0, (np.trace(R) - 1.0) / 2.0))
    angle = math.acos(cos)
    vee = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if angle < 1e-7:
        return 0.5 * vee
    if math.pi - angle < 1e-4:  # near a half turn: the axis from R + I's largest column
        S = 0.5 * (R + np.eye(3))
        axis = S[:, int(np.argmax(np.diagonal(S)))]
        axis = axis / np.linalg.norm(axis)
        if np.dot(axis, vee) < 0:
            axis = -axis
        return angle * axis
    return angle / (2.0 * math.sin(angle)) * vee


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """The geodesic angle between two rotations, in degrees."""
    return math.degrees(float(np.linalg.norm(log_so3(np.asarray(R_a).T @ np.asarray(R_b)))))


@dataclass(frozen=True)
class Pose:
    """x_ref = scale R x_obj + t: the object (decoder frame) in a reference camera's frame."""

    R: np.ndarray  # [3, 3]
    t: np.ndarray  # [3]
    scale: float = 1.0

    @classmethod
    def from_world_to_cam(cls, world_to_cam: np.ndarray, scale: float = 1.0) -> "Pose":
        """The pose a rigid object-frame camera gives (its object seen at `scale`: t is scaled with it)."""
        w2c = np.asarray(world_to_cam, dtype=np.float64)
        return cls(w2c[:3, :3].copy(), scale * w2c[:3, 3].copy(), float(scale))

    def perturbed(self, xi: np.ndarray) -> "Pose":
        """T o delta(xi) for xi = (omega [3], v [3]) or (omega, v, sigma) [7] (module docstring)."""
        xi = np.asarray(xi, dtype=np.float64)
        sigma = float(xi[6]) if xi.shape[0] > 6 else 0.0
        return Pose(
            self.R @ exp_so3(xi[ROTATION]), self.t + self.scale * self.R @ xi[TRANSLATION], self.scale * math.exp(sigma)
        )

    def object_camera(self, cam_from_ref: np.ndarray) -> np.ndarray:
        """world_to_cam [4, 4] (rigid, object units) of a camera at cam_from_ref [4, 4] from the reference."""
        cam_from_ref = np.asarray(cam_from_ref, dtype=np.float64)
        out = np.eye(4)
        out[:3, :3] = cam_from_ref[:3, :3] @ self.R
        out[:3, 3] = (cam_from_ref[:3, :3] @ self.t + cam_from_ref[:3, 3]) / self.scale
        return out

    def error(self, truth: "Pose") -> np.ndarray:
        """(omega, v, sigma) [7] that takes this pose to `truth` (truth = self o delta), to first order in v."""
        omega = log_so3(self.R.T @ truth.R)
        v = self.R.T @ (truth.t - self.t) / self.scale
        return np.concatenate([omega, v, [math.log(truth.scale / self.scale)]])


def point_jacobian(
    points: Tensor,  # [N, 3] object-frame points held fixed in the camera
    grad_x: Tensor,  # [N, 3] ds/dx at them
    dofs: int = 6,  # 6: rotation and translation; 7: and log scale
) -> Tensor:  # [N, dofs]
    """ds/dxi of the SDF at camera-fixed points under the object-side perturbation (module docstring)."""
    columns = [torch.linalg.cross(grad_x, points, dim=-1), -grad_x]
    if dofs == 7:
        columns.append(-(grad_x * points).sum(-1, keepdim=True))
    elif dofs != 6:
        raise ValueError(f"a pose has 6 (rotation, translation) or 7 (and scale) degrees of freedom, got {dofs}")
    return torch.cat(columns, dim=-1)


def scale_observable(cams_from_ref: list[np.ndarray], min_baseline: float = 1e-3) -> bool:
    """Whether views with these motions from the reference can tell the object's size (a baseline between them)."""
    centres = [-np.asarray(c)[:3, :3].T @ np.asarray(c)[:3, 3] for c in cams_from_ref]
    return any(np.linalg.norm(c - centres[0]) > min_baseline for c in centres[1:])
