"""Coarse-to-fine evaluation of the projection network on an exact set's lattice.

K at an instant is {W <= level} cut to the outer polygon (``reach.engine.FieldTubeSet``): the
network only matters at nodes where W comes near its level. W is evaluated first on every other
node in both directions (a quarter of them); a remaining node is evaluated only when a coarse node
within two steps lies within ``tau`` of the level, or when none of its immediate coarse neighbours
was evaluated (the rim of the polygon). Every other node is taken as inside for the network (its
field is the polygon's alone), so the set can only grow: it still contains the model's set
{W <= level} ∩ polygon, and equals it wherever the margin holds.

``tau`` bounds how much W can change between a node and its coarse neighbour (at most one diagonal
step away): twice the steepest change the coarse nodes themselves show, times that distance.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

#: tau = SAFETY * (steepest coarse slope) * (diagonal step).
SAFETY = 2.0
#: Floor of tau in units of W (metres): a flat coarse field still refines near the level.
TAU_FLOOR = 0.25


@dataclass(frozen=True)
class Refinement:
    """W at every node of ``inside`` (np.nonzero order; -inf where skipped), and the counts."""

    values: np.ndarray
    evaluated: int
    skipped: int


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """[J, H, W] boolean mask grown by ``radius`` nodes in both directions (a square), one axis
    after the other."""
    out = mask.copy()
    for axis in (1, 2):
        grown = out.copy()
        for shift in range(1, radius + 1):
            ahead = [slice(None)] * 3
            behind = [slice(None)] * 3
            ahead[axis], behind[axis] = slice(shift, None), slice(None, -shift)
            grown[tuple(ahead)] |= out[tuple(behind)]
            grown[tuple(behind)] |= out[tuple(ahead)]
        out = grown
    return out


def coarse_nodes(inside: np.ndarray, k0: np.ndarray, i0: np.ndarray) -> np.ndarray:
    """The nodes of ``inside`` whose absolute lattice row and column are both even."""
    _, height, width = inside.shape
    even_row = (k0[:, None, None] + np.arange(height)[None, :, None]) % 2 == 0
    even_col = (i0[:, None, None] + np.arange(width)[None, None, :]) % 2 == 0
    return inside & even_row & even_col


def steepest_coarse_slope(excess: np.ndarray, step: float) -> float:
    """Largest |change of W| per metre between coarse nodes two steps apart (nan if none)."""
    with np.errstate(invalid="ignore"):  # inf - inf between two far nodes: nan, dropped below
        along_x = np.abs(excess[:, :, 2:] - excess[:, :, :-2])
        along_y = np.abs(excess[:, 2:, :] - excess[:, :-2, :])
    finite = [a[np.isfinite(a)] for a in (along_x, along_y)]
    if not any(len(a) for a in finite):
        return math.nan
    return float(max(a.max() for a in finite if len(a))) / (2.0 * step)


def coarse_to_fine(
    inside: np.ndarray,
    k0: np.ndarray,
    i0: np.ndarray,
    step: float,
    levels: np.ndarray,
    evaluate: Callable[[np.ndarray], np.ndarray],
) -> Refinement:
    """W at the nodes of ``inside`` [J, H, W] (windows at lattice offsets ``k0``, ``i0``), with
    ``levels`` [J] the calibrated level per instant; ``evaluate(mask)`` returns W at the nodes of
    ``mask`` in np.nonzero order."""
    coarse = coarse_nodes(inside, k0, i0)
    at = np.nonzero(coarse)
    excess = np.full(inside.shape, np.nan)
    w_coarse = np.asarray(evaluate(coarse), dtype=np.float64).reshape(-1)
    excess[at] = w_coarse - levels[at[0]]
    slope = steepest_coarse_slope(excess, step)
    fine = inside & ~coarse
    if math.isfinite(slope):
        tau = max(SAFETY * slope * step * math.sqrt(2.0), TAU_FLOOR)
        hot = coarse & (excess > -tau)
        cold = coarse & (excess <= -tau)
        fine &= dilate(hot, 2) | ~dilate(cold, 1)
    values = np.full(inside.shape, -np.inf)
    values[at] = w_coarse
    if fine.any():
        values[fine] = np.asarray(evaluate(fine), dtype=np.float64).reshape(-1)
    evaluated = int(coarse.sum() + fine.sum())
    return Refinement(
        values=values[inside], evaluated=evaluated, skipped=int(inside.sum()) - evaluated
    )
