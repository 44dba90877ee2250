"""Per-instant fields of one exact set, computed for every instant at once.

An exact set (``reach.engine.FRTEngine.exact``) samples fields on one lattice, each instant in its
own window (the outer-bound sweeps around that instant). Doing that window by window is many small
numpy calls per instant; here every window is padded to one shape ``(H, W)`` and the instants are
stacked into ``[J, H, W]`` arrays, so each step is a handful of numpy calls for all instants. Nodes
outside an instant's own window hold ``FAR`` (+inf) exactly as the per-window fields had none
there, so :meth:`WindowStack.crop` gives back the same windows and values.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

#: Stands for "+inf" in a contoured field (contourpy needs finite values).
FAR = 1.0e6


def block_reduce(values: np.ndarray, k: int, ufunc: np.ufunc) -> np.ndarray:
    """``ufunc`` over consecutive blocks of ``k`` rows: [n, ...] -> [ceil(n / k), ...]."""
    return ufunc.reduceat(values, np.arange(0, len(values), k), axis=0)  # type: ignore[no-any-return]


def span_reduce(blocks: np.ndarray, ufunc: np.ufunc) -> np.ndarray:
    """Per instant j, ``ufunc`` of the blocks either side of it (j - 1 and j; one at the ends):
    [J - 1, ...] -> [J, ...]."""
    out = np.empty((len(blocks) + 1, *blocks.shape[1:]), dtype=blocks.dtype)
    out[0] = blocks[0]
    out[-1] = blocks[-1]
    out[1:-1] = ufunc(blocks[:-1], blocks[1:])
    return out


@dataclass(frozen=True)
class WindowStack:
    """Windows [k0, k0 + h) x [i0, i0 + w) of a lattice (rows k along y, columns i along x), one
    per instant, padded to the common shape ``(H, W)``; ``xs``/``ys`` are the padded windows' node
    coordinates ([J, W] and [J, H])."""

    k0: np.ndarray
    i0: np.ndarray
    h: np.ndarray
    w: np.ndarray
    xs: np.ndarray
    ys: np.ndarray

    @classmethod
    def make(
        cls,
        lo: np.ndarray,
        hi: np.ndarray,
        origin: tuple[float, float],
        step: float,
        size: tuple[int, int],
    ) -> WindowStack:
        """Windows covering boxes ``lo``..``hi`` ([J, 2]: x, y) with one node of margin below and
        two above, clipped to a lattice of ``size`` = (nx, ny) nodes from ``origin``."""
        x0, y0 = origin
        i0 = np.maximum(np.floor((lo[:, 0] - x0) / step).astype(np.int64) - 1, 0)
        i1 = np.minimum(np.ceil((hi[:, 0] - x0) / step).astype(np.int64) + 2, size[0])
        k0 = np.maximum(np.floor((lo[:, 1] - y0) / step).astype(np.int64) - 1, 0)
        k1 = np.minimum(np.ceil((hi[:, 1] - y0) / step).astype(np.int64) + 2, size[1])
        w, h = i1 - i0, k1 - k0
        xs = x0 + step * (i0[:, None] + np.arange(int(w.max()))[None, :])
        ys = y0 + step * (k0[:, None] + np.arange(int(h.max()))[None, :])
        return cls(k0=k0, i0=i0, h=h, w=w, xs=xs, ys=ys)

    @property
    def shape(self) -> tuple[int, int, int]:
        return (len(self.k0), self.ys.shape[1], self.xs.shape[1])

    def valid(self) -> np.ndarray:
        """[J, H, W]: the node lies in its instant's own window."""
        _, height, width = self.shape
        rows = np.arange(height)[None, :, None] < self.h[:, None, None]
        cols = np.arange(width)[None, None, :] < self.w[:, None, None]
        return rows & cols

    def crop(self, stack: np.ndarray, j: int) -> np.ndarray:
        """Instant j's own window of a [J, H, W] stack."""
        return stack[j, : self.h[j], : self.w[j]]

    def polygon_fields(
        self, directions: np.ndarray, supports: list[np.ndarray], valid: np.ndarray
    ) -> list[np.ndarray]:
        """Per support stack S [J, M] of ``supports``: max over m of (node . n_m - S[j, m]) at every
        node of every window ([J, H, W], float64; <= 0 exactly inside instant j's polygon of
        support S[j]). Computed at the ``valid`` nodes only (compiled, ``_polygon_fields``); the
        others hold +inf."""
        angles = np.asarray(directions, dtype=np.float64)
        out = _polygon_fields(
            np.ascontiguousarray(self.xs, dtype=np.float64),
            np.ascontiguousarray(self.ys, dtype=np.float64),
            np.ascontiguousarray(valid),
            np.cos(angles),
            np.sin(angles),
            np.ascontiguousarray(np.stack(supports), dtype=np.float64),
        )
        return list(out)

    def nodes_inside(self, directions: np.ndarray, supports: np.ndarray, limit: int) -> np.ndarray:
        """Per window j, how many of its own nodes lie inside instant j's polygon of support
        ``supports[j]`` as :meth:`polygon_fields` draws it (its value there, rounded to float32,
        is <= 0), counted up to ``limit`` ([J] int: ``limit`` where there are as many or more).
        Compiled (``_nodes_inside``, the rows nearest the window's middle first)."""
        angles = np.asarray(directions, dtype=np.float64)
        return _nodes_inside(  # type: ignore[no-any-return]
            np.ascontiguousarray(self.xs, dtype=np.float64),
            np.ascontiguousarray(self.ys, dtype=np.float64),
            self.h,
            self.w,
            np.cos(angles),
            np.sin(angles),
            np.ascontiguousarray(supports, dtype=np.float64),
            limit,
        )

    def shifted(self, stack: np.ndarray, src: int, dst: int) -> np.ndarray:
        """Window ``src``'s values of ``stack`` seen from window ``dst`` ([H, W]; FAR where ``src``
        has none)."""
        _, height, width = self.shape
        out = np.full((height, width), FAR, dtype=stack.dtype)
        dk = int(self.k0[dst] - self.k0[src])
        di = int(self.i0[dst] - self.i0[src])
        # Rows r of dst hold rows r + dk of src, for 0 <= r + dk < src's own height.
        r0, r1 = max(0, -dk), min(height, int(self.h[src]) - dk)
        c0, c1 = max(0, -di), min(width, int(self.w[src]) - di)
        if r1 > r0 and c1 > c0:
            out[r0:r1, c0:c1] = stack[src, r0 + dk : r1 + dk, c0 + di : c1 + di]
        return out

    def interval_fields(
        self,
        field: np.ndarray,
        grown: np.ndarray,
        interval: np.ndarray,
        valid: np.ndarray,
        band: np.float32,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per interval j >= 1, the field max(min(``grown[j]``, ``grown[j - 1]`` seen from window
        j), ``interval[j]``) ([J, H, W]; slot 0 holds ``field[0]``; FAR at the nodes not ``valid``,
        where ``grown`` is set to FAR too), and whether the interval is held by its polygon: at
        every valid node of window j, the minimum is <= 0 where ``interval[j]`` is, and <= it
        where ``|interval[j]|`` <= ``band`` ([J] bool, False at 0). Compiled
        (``_interval_fields``), with ``np.minimum``'s and ``np.maximum``'s choices."""
        return _interval_fields(  # type: ignore[no-any-return]
            field, grown, interval, valid, self.k0, self.i0, self.h, self.w, band
        )


@numba.njit(cache=True)
def _polygon_fields(
    xs: np.ndarray,
    ys: np.ndarray,
    valid: np.ndarray,
    cosines: np.ndarray,
    sines: np.ndarray,
    supports: np.ndarray,
) -> np.ndarray:
    """max over m of (x cos_m + y sin_m - supports[s, j, m]) at each valid node (x = xs[j, w],
    y = ys[j, h]) of each window j, for each support stack s: [S, J, H, W], +inf elsewhere."""
    stacks, count, directions = supports.shape
    height, width = valid.shape[1], valid.shape[2]
    out = np.full((stacks, count, height, width), np.inf)
    for j in range(count):
        for h in range(height):
            y = ys[j, h]
            for w in range(width):
                if not valid[j, h, w]:
                    continue
                x = xs[j, w]
                for s in range(stacks):
                    best = -np.inf
                    for m in range(directions):
                        along = x * cosines[m] + y * sines[m] - supports[s, j, m]
                        if along > best:
                            best = along
                    out[s, j, h, w] = best
    return out


@numba.njit(cache=True)
def _nodes_inside(
    xs: np.ndarray,
    ys: np.ndarray,
    heights: np.ndarray,
    widths: np.ndarray,
    cosines: np.ndarray,
    sines: np.ndarray,
    supports: np.ndarray,
    limit: int,
) -> np.ndarray:
    """``WindowStack.nodes_inside``: each node's value as ``_polygon_fields`` computes it, rounded
    to float32, compared with 0; rows from the middle of the window outwards, stopping at
    ``limit``."""
    count, directions = supports.shape
    inside = np.zeros(count, dtype=np.int64)
    for j in range(count):
        rows, middle = heights[j], heights[j] // 2
        for i in range(2 * rows):  # middle, middle + 1, middle - 1, middle + 2, ...
            h = middle + (i + 1) // 2 if i % 2 else middle - i // 2
            if h < 0 or h >= rows:
                continue
            y = ys[j, h]
            for w in range(widths[j]):
                x = xs[j, w]
                best = -np.inf
                for m in range(directions):
                    along = x * cosines[m] + y * sines[m] - supports[j, m]
                    if along > best:
                        best = along
                if np.float32(best) <= 0:
                    inside[j] += 1
            if inside[j] >= limit:
                inside[j] = limit
                break
    return inside


def compile_field_kernels() -> None:
    """Compile (or load from numba's cache) the kernels of this module before a set needs them
    (the first compilation after a change takes seconds), for the engine's float32 fields."""
    one = np.zeros((1, 1))
    _polygon_fields(
        one, one, np.ones((1, 1, 1), dtype=np.bool_), one[0], one[0], np.zeros((1, 1, 1))
    )
    field = np.zeros((2, 1, 1), dtype=np.float32)
    grown = dilate_discs(
        field, np.ones(2), (np.ones(2, dtype=np.int64), np.ones(2, dtype=np.int64))
    )
    stack = WindowStack.make(np.zeros((2, 2)), np.ones((2, 2)), (0.0, 0.0), 1.0, (4, 4))
    stack.interval_fields(field, grown, field, np.ones((2, 1, 1), dtype=np.bool_), np.float32(1.0))
    stack.nodes_inside(np.zeros(1), np.zeros((2, 1)), 16)


def dilate_discs(
    values: np.ndarray,
    radii_nodes: np.ndarray,
    extents: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Per instant j, the min of ``values[j]`` over the nodes within ``radii_nodes[j]`` (Euclidean)
    of each node; nodes beyond the array count as +inf (``FAR``). On a field whose zero sublevel
    set is K, the result's is K grown by that radius (grid dilation). With ``extents`` (heights
    and widths [J]) only instant j's nodes [0, h_j) x [0, w_j) are read and computed, the others
    counting as and coming out FAR (a window stack's own windows: :meth:`WindowStack.valid`).

    Compiled (``_dilate_discs``): each node takes the minimum with its neighbours in the order of
    their offsets (row offset, then column offset, increasing), with ``np.minimum``'s choice, so
    the result is the one of numpy minima taken offset by offset over the whole array."""
    count, height, width = values.shape
    r = math.floor(float(np.max(radii_nodes))) if count else 0
    squared = np.asarray(radii_nodes * radii_nodes, dtype=np.float64)
    if extents is None:
        heights, widths = np.full(count, height), np.full(count, width)
    else:
        heights, widths = extents
    return _dilate_discs(  # type: ignore[no-any-return]
        np.ascontiguousarray(values),
        squared,
        r,
        np.asarray(heights, dtype=np.int64),
        np.asarray(widths, dtype=np.int64),
    )


@numba.njit(inline="always")
def _smaller(a: float, b: float) -> float:
    """``np.minimum(a, b)``: a NaN of either, else the smaller, ``b`` when they are equal."""
    return a if (a != a or a < b) else b


@numba.njit(inline="always")
def _larger(a: float, b: float) -> float:
    """``np.maximum(a, b)``: a NaN of either, else the larger, ``b`` when they are equal."""
    return a if (a != a or a > b) else b


@numba.njit(cache=True)
def _dilate_discs(
    values: np.ndarray, squared: np.ndarray, r: int, heights: np.ndarray, widths: np.ndarray
) -> np.ndarray:
    """``dilate_discs`` with the squared radii ``squared`` [J] (float64), the largest offset ``r``
    and each instant's extent: node (j, h, w) takes in turn the minimum with each node
    (h + dk, w + di) of dk^2 + di^2 <= squared[j], FAR beyond the extent."""
    count, height, width = values.shape
    padded = np.empty((count, height + 2 * r, width + 2 * r), dtype=values.dtype)
    padded[:] = FAR
    out = np.empty_like(values)
    out[:] = FAR
    for j in range(count):
        rows, cols = heights[j], widths[j]
        padded[j, r : r + rows, r : r + cols] = values[j, :rows, :cols]
        out[j, :rows, :cols] = values[j, :rows, :cols]
        for dk in range(-r, r + 1):
            for di in range(-r, r + 1):
                d2 = dk * dk + di * di
                if d2 == 0 or not d2 <= squared[j]:
                    continue
                for h in range(rows):
                    row = out[j, h, :cols]
                    seen = padded[j, r + dk + h, r + di : r + di + cols]
                    for w in range(cols):
                        row[w] = _smaller(row[w], seen[w])
    return out


@numba.njit(cache=True)
def _interval_fields(
    field: np.ndarray,
    grown: np.ndarray,
    interval: np.ndarray,
    valid: np.ndarray,
    k0: np.ndarray,
    i0: np.ndarray,
    h: np.ndarray,
    w: np.ndarray,
    band: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``WindowStack.interval_fields`` on the windows (``k0``, ``i0``, ``h``, ``w``); ``grown`` is
    overwritten with FAR at the nodes not ``valid``."""
    count, height, width = field.shape
    for j in range(count):
        for row in range(height):
            for col in range(width):
                if not valid[j, row, col]:
                    grown[j, row, col] = FAR
    sweep = np.empty_like(field)
    sweep[0] = field[0]
    held = np.zeros(count, dtype=np.bool_)
    near = np.empty((height, width), dtype=field.dtype)
    for j in range(1, count):
        dk, di = k0[j] - k0[j - 1], i0[j] - i0[j - 1]
        inside_ok, edge_ok = True, True
        for row in range(height):
            for col in range(width):
                rr, cc = row + dk, col + di
                before = grown[j - 1, rr, cc] if 0 <= rr < h[j - 1] and 0 <= cc < w[j - 1] else FAR
                value = _smaller(grown[j, row, col], before)
                near[row, col] = value
                polygon = interval[j, row, col]
                if valid[j, row, col]:
                    inside_ok &= not polygon <= 0 or value <= 0
                    edge_ok &= not abs(polygon) <= band or near[row, col] <= polygon
                sweep[j, row, col] = _larger(near[row, col], polygon)
        held[j] = inside_ok and edge_ok
    for j in range(count):
        for row in range(height):
            for col in range(width):
                if not valid[j, row, col]:
                    sweep[j, row, col] = FAR
    return sweep, held
