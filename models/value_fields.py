"""The shipped network as a ``reach.value_field.ValueField``: what plugs it into the engine.

Two fields over one ``models.runtime.ValueModel`` (onnxruntime, no torch):

* ``ProjectionField``: W(s, x, y), the distilled minimum of V over heading and speed
  (``models.projection``), one evaluation per node; its level is the card's ``projection_graph``
  calibration, ``level_offset_m + level_per_scale * box_scale`` of the instant's outer box.
* ``StencilField``: the minimum of V over a small heading/speed stencil around the arc-consistent
  guess (the projection's teacher), nine evaluations per node; its level is the card's
  ``projection.delta``.

``engine_for`` builds an ``FRTEngine`` with the card's horizon, initial set and trained ranges.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from models.runtime import ModelCard, ValueModel
from reach.contract import COL, N_INPUTS, PARAM_COLUMNS, InitialSet
from reach.dynamics import wrap_angle
from reach.engine import FRTEngine
from reach.outer_bound import OuterBound, box_scale


def _covers(card: ModelCard, v_start: float, bounds: np.ndarray) -> bool:
    """Whether every parameter of the setting lies in the card's trained ranges."""
    values = (float(v_start), *(float(b) for b in bounds))
    return all(
        card.ranges[name][0] - 1e-9 <= value <= card.ranges[name][1] + 1e-9
        for name, value in zip(PARAM_COLUMNS, values, strict=True)
    )


def _inputs(
    times: np.ndarray | float, px: np.ndarray, py: np.ndarray, v_start: float, bounds: np.ndarray
) -> np.ndarray:
    """The contract's [N, 14] input at heading 0 and speed 0 for the points (px, py)."""
    x = np.zeros((len(px), N_INPUTS), dtype=np.float32)
    x[:, COL["t"]] = times
    x[:, COL["px"]] = px
    x[:, COL["py"]] = py
    x[:, COL["v_start"]] = v_start
    x[:, COL["u1_min_start"] :] = bounds
    return x


class ProjectionField:
    """W(s, x, y) of the distilled projection graph, at its calibrated level."""

    name = "projection"

    def __init__(self, model: ValueModel) -> None:
        if model.projection is None:
            raise ValueError("the model has no projection graph")
        self.model = model
        listed = model.card.raw["projection_graph"]
        self.level = float(listed["delta"])
        per_scale = listed.get("level_per_scale")
        #: If set, the level at an instant is ``level_offset_m`` plus this times the outer box's
        #: scale (``box_scale``); else ``level``.
        self.level_per_scale: float | None = None if per_scale is None else float(per_scale)
        self.level_offset_m = float(listed.get("level_offset_m", 0.0))

    def covers(self, v_start: float, bounds: np.ndarray) -> bool:
        return _covers(self.model.card, v_start, bounds)

    def levels(self, outer_boxes: np.ndarray) -> np.ndarray:
        if self.level_per_scale is None:
            return np.full(len(outer_boxes), self.level)
        return self.level_offset_m + self.level_per_scale * box_scale(outer_boxes)

    def values(
        self,
        times: np.ndarray,
        px: np.ndarray,
        py: np.ndarray,
        v_start: float,
        bounds: np.ndarray,
        bound: OuterBound,
    ) -> tuple[np.ndarray, int]:
        return self.projected(times, px, py, v_start, bounds), len(px)

    def projected(
        self,
        times: np.ndarray | float,
        px: np.ndarray,
        py: np.ndarray,
        v_start: float,
        bounds: np.ndarray,
    ) -> np.ndarray:
        """W at the points, one evaluation each."""
        return self.model.evaluate_projection(_inputs(times, px, py, v_start, bounds))


class StencilField:
    """The minimum of V over a heading x speed stencil at each point, at the card's level."""

    name = "stencil"

    def __init__(self, model: ValueModel, heading_samples: int = 3, speed_samples: int = 3) -> None:
        self.model = model
        self.heading_samples = heading_samples
        self.speed_samples = speed_samples
        stencil = model.card.raw.get("projection") or {}
        self.level = float(stencil.get("delta", model.card.delta))

    def covers(self, v_start: float, bounds: np.ndarray) -> bool:
        return _covers(self.model.card, v_start, bounds)

    def levels(self, outer_boxes: np.ndarray) -> np.ndarray:
        return np.full(len(outer_boxes), self.level)

    def values(
        self,
        times: np.ndarray,
        px: np.ndarray,
        py: np.ndarray,
        v_start: float,
        bounds: np.ndarray,
        bound: OuterBound,
    ) -> tuple[np.ndarray, int]:
        values, evaluations = np.zeros(len(px), dtype=np.float32), 0
        for s in np.unique(times):
            rows = times == s
            v, n = self.stencil_min(float(s), px[rows], py[rows], v_start, bounds, bound)
            values[rows] = v
            evaluations += n
        return values, evaluations

    def stencil_min(
        self,
        s: float,
        px: np.ndarray,
        py: np.ndarray,
        v_start: float,
        bounds: np.ndarray,
        ob: OuterBound,
    ) -> tuple[np.ndarray, int]:
        """min over a heading/speed stencil of V(s, x, y, heading, speed) at the points (px, py).

        The stencil is centred on the arc-consistent heading 2 atan2(y, x) and on the speed that
        covers the arc's length in time s at constant acceleration, both clipped to the exact
        heading and speed intervals at s. Returns the minima and the number of evaluations.
        """
        k = ob.nearest_row(s)
        th_lo, th_hi = ob.heading[k]
        v_lo, v_hi = ob.speed[k]
        guess = np.clip(2.0 * np.arctan2(py, px), th_lo, th_hi)
        chord = np.hypot(px, py)
        half_turn = np.abs(guess) / 2
        arc = chord * np.where(half_turn > 1e-6, half_turn / np.maximum(np.sin(half_turn), 1e-6), 1)
        speed_guess = np.clip(2 * arc / max(s, 1e-6) - v_start, v_lo, v_hi)
        d_th = np.clip((th_hi - th_lo) / 4, 0.01, 0.3)
        d_v = np.clip((v_hi - v_lo) / 4, 0.02, 2.0)
        offsets_th = np.linspace(-1, 1, self.heading_samples) * d_th
        offsets_v = np.linspace(-1, 1, self.speed_samples) * d_v
        heading = np.clip(guess[:, None, None] + offsets_th[None, :, None], th_lo, th_hi)
        speed = np.clip(speed_guess[:, None, None] + offsets_v[None, None, :], v_lo, v_hi)
        shape = (len(px), self.heading_samples, self.speed_samples)
        heading = np.broadcast_to(heading, shape).ravel()
        speed = np.broadcast_to(speed, shape).ravel()
        per_point = shape[1] * shape[2]
        x = _inputs(s, np.repeat(px, per_point), np.repeat(py, per_point), v_start, bounds)
        x[:, COL["heading"]] = wrap_angle(heading)
        x[:, COL["speed"]] = speed
        return self.model.evaluate(x).reshape(shape).min(axis=(1, 2)), heading.size


def network_field(model: ValueModel, stencil: bool = False) -> ProjectionField | StencilField:
    """The model's projection field, or its stencil field where asked or it has no projection."""
    if stencil or model.projection is None:
        return StencilField(model)
    return ProjectionField(model)


def engine_for(
    model: ValueModel, network: bool = True, stencil: bool = False, **options: Any
) -> FRTEngine:
    """An engine with the card's horizon, initial set and trained ranges; cut by the model's
    field (``network_field``) unless ``network`` is False. The stencil field is evaluated at
    every node (it is the projection's teacher: no coarse-to-fine)."""
    card = model.card
    field = network_field(model, stencil) if network else None
    if isinstance(field, StencilField):
        options.setdefault("refine", False)
    return FRTEngine(
        field,
        horizon_s=card.horizon_s,
        initial_set=InitialSet(**card.initial_set),
        ranges={name: card.ranges[name] for name in PARAM_COLUMNS},
        **options,
    )


def card_says_network_cuts(card: ModelCard) -> bool | None:
    """What the card's evaluation found (``models.evaluate``): whether the network cut any
    evaluated tube inside the certified geometry; None if the card does not say."""
    summary = (card.raw.get("accuracy") or {}).get("summary") or {}
    if "network_cuts" in summary:
        return bool(summary["network_cuts"])
    if "rows_where_the_network_cuts" in summary:
        return int(summary["rows_where_the_network_cuts"]) > 0
    return None


def network_decision(card: ModelCard, mode: str) -> tuple[bool, str]:
    """Whether the service evaluates the network when it builds a set, and why. ``mode``: "on"
    (always), "off" (never), "auto" (unless the card's evaluation found that it cuts nothing)."""
    if mode == "on":
        return True, "forced on (FRT_NETWORK=on)"
    if mode == "off":
        return False, "forced off (FRT_NETWORK=off)"
    cuts = card_says_network_cuts(card)
    if cuts is False:
        return False, "the card's evaluation found that it cuts nothing inside the certified sets"
    if cuts is None:
        return True, "the card does not say whether it cuts: evaluated"
    return True, "the card's evaluation found that it cuts the certified sets"
