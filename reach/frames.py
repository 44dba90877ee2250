"""The human frame: origin at the human's observed position, x along its heading.

Every set is built in the human frame (the dynamics start at (0, 0, heading 0)); answers are in the
world frame: p_world = R(heading) p_human + (x, y), and back with R(-heading). Boxes are
(x0, y0, x1, y1) in whichever frame they are given.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from shapely import affinity
from shapely.geometry.base import BaseGeometry


@dataclass(frozen=True)
class Pose:
    """The human's world pose at the observation time."""

    x: float
    y: float
    heading: float


def human_frames(xy_world: np.ndarray, poses: Sequence[Pose]) -> tuple[np.ndarray, np.ndarray]:
    """World points [N, 2] in the frame of each of A humans (origin at the human, heading 0):
    x, y [A, N]. One definition for a single set and for a check of many."""
    c = np.array([math.cos(p.heading) for p in poses], dtype=np.float64)[:, None]
    s = np.array([math.sin(p.heading) for p in poses], dtype=np.float64)[:, None]
    dx = xy_world[None, :, 0] - np.array([p.x for p in poses], dtype=np.float64)[:, None]
    dy = xy_world[None, :, 1] - np.array([p.y for p in poses], dtype=np.float64)[:, None]
    return c * dx + s * dy, -s * dx + c * dy


def paired_human_frames(
    xy_world: np.ndarray, poses: Sequence[Pose]
) -> tuple[np.ndarray, np.ndarray]:
    """Each world point [P, 2] in the frame of its own human (``poses`` [P]): x, y [P], by the
    arithmetic of :func:`human_frames` (the same value for each pair)."""
    c = np.array([math.cos(p.heading) for p in poses])
    s = np.array([math.sin(p.heading) for p in poses])
    dx = xy_world[:, 0] - np.array([p.x for p in poses])
    dy = xy_world[:, 1] - np.array([p.y for p in poses])
    return c * dx + s * dy, -s * dx + c * dy


def to_human_frame(xy_world: np.ndarray, pose: Pose) -> np.ndarray:
    """World points [N, 2] -> the human frame (origin at the human, heading 0)."""
    x, y = human_frames(xy_world, [pose])
    return np.stack([x[0], y[0]], axis=1)


def to_world_frame(geometry: BaseGeometry, pose: Pose) -> BaseGeometry:
    c, s = math.cos(pose.heading), math.sin(pose.heading)
    return affinity.affine_transform(geometry, [c, -s, s, c, pose.x, pose.y])


def covers_box(outer: tuple[float, ...], inner: tuple[float, ...]) -> bool:
    """Whether the box ``outer`` holds the box ``inner`` (both x0, y0, x1, y1)."""
    return (
        outer[0] <= inner[0]
        and outer[1] <= inner[1]
        and outer[2] >= inner[2]
        and outer[3] >= inner[3]
    )
