"""What a conservative answer costs a planner: the fallback set's area against the exact set's.

A check whose exact set is not ready answers from the interval outer bound's boxes
(``reach.sets.BoxTubeSet``), which contain the exact set (``reach.field_tube.FieldTubeSet``, as
first served: before any notch cut). The ratio of their whole-horizon areas, of K and of
C = K ⊕ R_col, says how much more room a planner gives a human when it gets the fallback.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from reach.contract import PARAM_COLUMNS
from reach.engine import FRTEngine
from reach.frames import Pose

#: The eight control bounds in the model's order (the contract's parameter columns after v_start).
BOUND_NAMES: tuple[str, ...] = PARAM_COLUMNS[1:]


@dataclass(frozen=True)
class AreaRatio:
    """Conservative over exact whole-horizon area, of K and of C."""

    k: float
    c: float


def area_ratio(
    engine: FRTEngine, pose: Pose, v_start: float, bounds: Sequence[float], collision_radius: float
) -> AreaRatio:
    """The fallback's area over the exact set's, for one state and its control bounds."""
    b = np.asarray(bounds, dtype=np.float64)
    conservative = engine.conservative(pose, v_start, b)
    exact = engine.exact(pose, v_start, b)
    k_cons = conservative.tube(conservative.n_slices - 1)
    k_exact = exact.tube(exact.n_slices - 1)
    c_cons = k_cons.buffer(collision_radius, quad_segs=8)
    c_exact = k_exact.buffer(collision_radius, quad_segs=8)
    return AreaRatio(
        k=k_cons.area / max(k_exact.area, 1e-9), c=c_cons.area / max(c_exact.area, 1e-9)
    )


def mean_ratio(ratios: Iterable[AreaRatio]) -> AreaRatio:
    """The mean of each ratio (NaN for none)."""
    rows = list(ratios)
    if not rows:
        return AreaRatio(float("nan"), float("nan"))
    return AreaRatio(k=float(np.mean([r.k for r in rows])), c=float(np.mean([r.c for r in rows])))


def served_engine(model_path: Path) -> FRTEngine:
    """The engine the server builds from ``model_path`` (the network as its card decides)."""
    from models.runtime import ValueModel
    from models.value_fields import engine_for, network_decision

    model = ValueModel.load(model_path)
    network, _ = network_decision(model.card, "auto")
    return engine_for(model, network=network)
