"""The evaluation set: named FRT parameter settings spanning the trained ranges.

Each setting is v_start and, per control, (lo_start, hi_start, lo_end, hi_end). They cover
near-stationary and fast cars, narrow (high-confidence) and wide (low-confidence, at the limits)
bounds, asymmetric bounds, and bounds that shrink, grow or shift over the horizon.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reach.contract import BOUND_COLUMNS


@dataclass(frozen=True)
class Setting:
    name: str
    v_start: float
    u1: tuple[float, float, float, float]  # lo_start, hi_start, lo_end, hi_end
    u2: tuple[float, float, float, float]

    def bounds(self) -> np.ndarray:
        """The 8 bound columns in contract order."""
        u1_lo_s, u1_hi_s, u1_lo_e, u1_hi_e = self.u1
        u2_lo_s, u2_hi_s, u2_lo_e, u2_hi_e = self.u2
        values = {
            "u1_min_start": u1_lo_s,
            "u2_min_start": u2_lo_s,
            "u1_min_end": u1_lo_e,
            "u2_min_end": u2_lo_e,
            "u1_max_start": u1_hi_s,
            "u2_max_start": u2_hi_s,
            "u1_max_end": u1_hi_e,
            "u2_max_end": u2_hi_e,
        }
        return np.array([values[c] for c in BOUND_COLUMNS], dtype=float)


def const(lo: float, hi: float) -> tuple[float, float, float, float]:
    return (lo, hi, lo, hi)


SETTINGS: tuple[Setting, ...] = (
    Setting("stationary_narrow", 0.0, const(-0.05, 0.05), const(-0.2, 0.2)),
    Setting("stationary_wide_limits", 0.0, const(-2.0, 2.0), const(-10.0, 10.0)),
    Setting("creeping", 1.0, const(-0.3, 0.3), const(-1.0, 1.0)),
    Setting("urban_narrow", 8.0, const(-0.05, 0.05), const(-0.5, 0.5)),
    Setting("urban_medium", 8.0, const(-0.3, 0.3), const(-2.0, 2.0)),
    Setting("urban_wide", 8.0, const(-1.2, 1.2), const(-6.0, 6.0)),
    Setting("fast_narrow", 15.0, const(-0.03, 0.03), const(-0.5, 0.5)),
    Setting("fast_medium_asym", 15.0, const(-0.2, 0.2), const(-3.0, 2.0)),
    Setting("fast_wide_limits", 15.0, const(-2.0, 2.0), const(-10.0, 10.0)),
    Setting("max_speed_narrow", 20.0, const(-0.02, 0.02), const(-0.3, 0.3)),
    Setting("left_turn", 6.0, const(0.2, 0.6), const(-1.0, 1.0)),
    Setting("right_turn_asym", 6.0, const(-0.8, -0.1), const(-2.0, 0.5)),
    Setting("braking_hard", 12.0, const(-0.1, 0.1), const(-8.0, -4.0)),
    Setting("braking_to_stop", 4.0, const(-0.2, 0.2), const(-6.0, -2.0)),
    Setting("accelerating_from_slow", 2.0, const(-0.1, 0.1), const(2.0, 4.0)),
    Setting("shrinking_wide_to_narrow", 10.0, (-1.5, 1.5, -0.05, 0.05), (-8.0, 8.0, -0.5, 0.5)),
    Setting("shrinking_steering_only", 10.0, (-2.0, 2.0, -0.1, 0.1), const(-1.0, 1.0)),
    Setting("growing_narrow_to_wide", 10.0, (-0.05, 0.05, -1.5, 1.5), (-0.5, 0.5, -8.0, 8.0)),
    Setting("shifting_means", 8.0, (-0.4, -0.2, 0.2, 0.4), (0.0, 1.0, -2.0, -1.0)),
    Setting("u_turn_like", 3.0, (0.5, 1.0, 0.8, 1.2), const(0.0, 2.0)),
    Setting("stop_sign_runner", 2.0, const(-0.1, 0.1), (-1.0, 1.0, 1.0, 4.0)),
    Setting("low_confidence_urban", 5.0, const(-1.0, 1.0), const(-5.0, 5.0)),
)
