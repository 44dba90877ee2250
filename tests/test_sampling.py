"""Parameter samplers: every draw is a setting the model is trained for (inside the card's ranges,
u_min <= u_max at both ends), and the corner sampler stays at the edges it is meant for."""

from __future__ import annotations

import numpy as np

from models.sampling import (
    sample_corner_parameters,
    sample_parameters,
    sample_restart_parameters,
    sample_training_batch,
)
from reach.contract import BOUND_COLUMNS, COL, U1_LIMIT, U2_LIMIT, V_START_MAX


def _assert_admissible(x: np.ndarray) -> None:
    assert np.all((x[:, COL["v_start"]] >= 0) & (x[:, COL["v_start"]] <= V_START_MAX))
    for name in BOUND_COLUMNS:
        limit = U1_LIMIT if name.startswith("u1") else U2_LIMIT
        assert np.all(np.abs(x[:, COL[name]]) <= limit + 1e-12), name
    for dim in ("u1", "u2"):
        for end in ("start", "end"):
            assert np.all(x[:, COL[f"{dim}_min_{end}"]] <= x[:, COL[f"{dim}_max_{end}"]] + 1e-12)


def test_samplers_draw_admissible_settings() -> None:
    rng = np.random.default_rng(0)
    _assert_admissible(sample_parameters(5000, rng))
    corners = sample_corner_parameters(5000, rng)
    _assert_admissible(corners)
    assert corners[:, COL["v_start"]].min() >= 0.6 * V_START_MAX
    # Every corner interval touches a hard limit or spans zero (full width, hard, or wide).
    for dim, limit in (("u1", U1_LIMIT), ("u2", U2_LIMIT)):
        lo, hi = corners[:, COL[f"{dim}_min_start"]], corners[:, COL[f"{dim}_max_start"]]
        at_edge = np.isclose(lo, -limit) | np.isclose(hi, limit) | ((lo <= 0) & (hi >= 0))
        assert at_edge.all()
        assert np.mean(np.isclose(lo, -limit) & np.isclose(hi, limit)) > 0.3  # full width
    restarts = sample_restart_parameters(5000, rng)
    _assert_admissible(restarts)
    # Braking at the start, accelerating by the end (mostly strictly: the interval's middle).
    assert np.all(restarts[:, COL["u2_max_start"]] < 0)
    middle_end = 0.5 * (restarts[:, COL["u2_min_end"]] + restarts[:, COL["u2_max_end"]])
    assert np.all(middle_end > 0)


def test_corner_share_replaces_that_share_of_a_batch() -> None:
    plain = sample_training_batch(40, 2, 3.0, np.random.default_rng(1))
    mixed = sample_training_batch(40, 2, 3.0, np.random.default_rng(1), corner_share=0.5)
    fast = mixed.rollout_points[:40, COL["v_start"]]  # 20 settings x 2 points each
    assert fast.min() >= 0.6 * V_START_MAX
    assert not np.allclose(plain.rollout_points[:40], mixed.rollout_points[:40])
    _assert_admissible(mixed.pde_points)
