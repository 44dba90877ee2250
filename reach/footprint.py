"""The ego's footprint as discs: a box covered by equal discs along its axis.

A box of length L and width W is cut across its axis into n equal sections; the disc through the
corners of a section (centre at the section's centre, radius r = sqrt((L / 2n)^2 + (W / 2)^2))
contains it, so the n discs contain the box. A point of C within r of a disc centre may lie outside
the box, never the other way round: the distance from the box to C is at least
min_i d(c_i, C) - r, and a footprint whose discs all clear C clears it. A disc reaches past its
section by r - W / 2 across the axis and r - L / 2n along it (the corners lie on it), so the bound
is short of the box's distance by at most r - min(L / n, W) / 2 (the cover's *overreach*). n is
the smallest count that keeps the reach past the long sides, r - W / 2, within a tolerance, capped
at :data:`MAX_DISCS`; the end discs then reach further past the box's ends, as any disc through
both corners of an end with a radius near W / 2 must.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: The most discs one footprint is covered by (each costs one more point per trajectory point).
MAX_DISCS = 16
#: How far the cover may reach past the box's long sides by default (metres).
DEFAULT_SIDE_REACH = 0.1


@dataclass(frozen=True)
class DiscCover:
    """Disc centres at ``offsets`` (metres ahead of the reference point along the heading), each of
    ``radius``; together they contain the box."""

    offsets: np.ndarray
    radius: float
    half_width: float
    half_section: float

    @property
    def count(self) -> int:
        return len(self.offsets)

    @property
    def side_reach(self) -> float:
        """How far the discs reach past the box's long sides."""
        return self.radius - self.half_width

    @property
    def overreach(self) -> float:
        """How far the discs reach past the box at most: the most a footprint's clearance is
        short of the box's."""
        return self.radius - min(self.half_width, self.half_section)


def disc_cover(
    length: float,
    width: float,
    centre_ahead: float = 0.0,
    side_reach: float = DEFAULT_SIDE_REACH,
) -> DiscCover:
    """The cover of a ``length`` x ``width`` box whose centre lies ``centre_ahead`` metres ahead of
    the reference point along the heading, by the fewest discs (at most :data:`MAX_DISCS`) that
    reach at most ``side_reach`` past its long sides."""
    if not (length > 0.0 and width > 0.0 and side_reach > 0.0):
        raise ValueError("length, width and side_reach must be positive")
    half_width = width / 2.0
    # r - W/2 <= side_reach  <=>  L / 2n <= sqrt((W/2 + side_reach)^2 - (W/2)^2)
    longest = math.sqrt((half_width + side_reach) ** 2 - half_width**2)
    count = min(MAX_DISCS, max(1, math.ceil(length / (2.0 * longest) - 1e-12)))
    section = length / count
    offsets = centre_ahead - length / 2.0 + section * (np.arange(count) + 0.5)
    radius = math.hypot(section / 2.0, half_width)
    return DiscCover(
        offsets=offsets, radius=radius, half_width=half_width, half_section=section / 2.0
    )


def disc_centres(xy: np.ndarray, heading: np.ndarray, cover: DiscCover) -> np.ndarray:
    """The cover's disc centres ``[N * n, 2]`` for reference points ``xy [N, 2]`` with headings
    ``[N]``: the n discs of point k at rows ``k * n .. k * n + n - 1``, each ``xy + offset *
    (cos, sin)``."""
    cos, sin = np.cos(heading), np.sin(heading)
    centres = np.empty((len(cos), cover.count, 2))
    # Disc by disc over every point: numpy's broadcasting over a last axis of two is its slow case.
    for k, offset in enumerate(cover.offsets.tolist()):
        np.add(xy[:, 0], offset * cos, out=centres[:, k, 0])
        np.add(xy[:, 1], offset * sin, out=centres[:, k, 1])
    return centres.reshape(-1, 2)


def footprint_distances(disc_distances: np.ndarray, cover: DiscCover) -> np.ndarray:
    """Lower bounds ``[..., N]`` of each footprint's distance to a set, from the distances
    ``[..., N * n]`` of its disc centres to it (:func:`disc_centres`' order)."""
    shaped = disc_distances.reshape(*disc_distances.shape[:-1], -1, cover.count)
    # Disc by disc over every footprint: a minimum along a short last axis is numpy's slow case.
    least = shaped[..., 0].copy()
    for k in range(1, cover.count):
        np.minimum(least, shaped[..., k], out=least)
    return least - cover.radius
