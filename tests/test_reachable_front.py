"""The exact front of the reachable set, in closed form, against the rollouts and the served tube.

For constant bounds u1 in [-w, w] and u2 in [a_lo, a_hi] with a_hi >= 0, the support of the set
reached at time T in a direction d at angle phi in [0, pi/2] is exactly

    h(phi) = r + int_0^T (v0 + a_hi t) cos(min(theta0 + w t, phi) - phi) dt,

with r, theta0 = heading margin and v0 = v_start + speed margin from the initial set: pointwise,
v(t) <= v0 + a_hi t, and the admissible heading nearest phi is min(theta0 + w t, phi), whose cosine
is non-negative for these phi. The bound is attained by the trajectory that starts on the rim of the
initial disc in direction phi, turns at full rate until its heading is phi, then drives straight at
full throttle. This ground truth owes nothing to the network, the outer bound or the rollouts.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely

from models.eval_settings import SETTINGS, Setting, const
from models.evaluate import simulate
from models.rollout import rk4_rollout, sample_control_schedules, sample_initial_states
from reach.contract import COL, HORIZON_S, INITIAL_SET, N_INPUTS
from reach.outer_bound import outer_bound

ROOT = Path(__file__).resolve().parent.parent
MODEL = ROOT / "models" / "frt_unicycle.onnx"
PHIS = np.linspace(0.0, math.pi / 2, 7)
CASES = ("fast_wide_limits", "urban_wide", "left_turn_free", "urban_narrow")


def _bounds(name: str) -> tuple[float, float, float, float]:
    """(v_start, w, a_lo, a_hi) of a symmetric-steering setting."""
    if name == "left_turn_free":  # not in the evaluation set: its own constant bounds
        return 6.0, 0.6, -1.0, 1.0
    s = next(s for s in SETTINGS if s.name == name)
    assert s.u1[0] == -s.u1[1] and s.u1[:2] == s.u1[2:] and s.u2[:2] == s.u2[2:]
    return s.v_start, s.u1[1], s.u2[0], s.u2[1]


def _bound_columns(w: float, a_lo: float, a_hi: float) -> np.ndarray:
    return Setting("constant", 0.0, const(-w, w), const(a_lo, a_hi)).bounds()


def extreme_point(v_start: float, w: float, a_hi: float, phi: float, t_end: float) -> np.ndarray:
    """End point at t_end of the trajectory that attains h(phi) (fine trapezoid quadrature)."""
    m = INITIAL_SET
    t = np.linspace(0.0, t_end, 200_001)
    speed = v_start + m.speed_margin_mps + a_hi * t
    heading = np.minimum(m.heading_margin_rad + w * t, phi)
    vx, vy = speed * np.cos(heading), speed * np.sin(heading)
    dt = t[1] - t[0]
    x = m.radius_m * math.cos(phi) + dt * (vx.sum() - 0.5 * (vx[0] + vx[-1]))
    y = m.radius_m * math.sin(phi) + dt * (vy.sum() - 0.5 * (vy[0] + vy[-1]))
    return np.array([x, y])


def support(point: np.ndarray, phi: float) -> float:
    return float(point @ np.array([math.cos(phi), math.sin(phi)]))


@pytest.mark.parametrize("name", CASES)
def test_rollout_reference_reaches_the_exact_front(name: str) -> None:
    """The evaluation's inner reference gets within 1 % of the true front and never past it."""
    v_start, w, a_lo, a_hi = _bounds(name)
    roll = simulate(v_start, _bound_columns(w, a_lo, a_hi), 16384, np.random.default_rng(3))
    final = roll.states[-1, :, :2]
    for phi in PHIS:
        exact = support(extreme_point(v_start, w, a_hi, phi, HORIZON_S), phi)
        sampled = float((final @ np.array([math.cos(phi), math.sin(phi)])).max())
        assert sampled <= exact + 1e-3, f"phi={phi:.2f}: rollout beyond the exact front"
        assert sampled >= exact - 0.01 * exact, f"phi={phi:.2f}: {sampled:.2f} vs {exact:.2f}"


def test_switching_schedules_alone_fall_short_of_the_front() -> None:
    """Why the reference needs its turn-then-straight family: random bang-bang switching between
    the bounds misses the sideways front of a wide setting by metres."""
    v_start, w, a_lo, a_hi = _bounds("fast_wide_limits")
    bounds = _bound_columns(w, a_lo, a_hi)
    rng = np.random.default_rng(3)
    n = 16384
    params = np.zeros((n, N_INPUTS))
    params[:, 6:] = bounds
    params[:, COL["v_start"]] = v_start
    start = sample_initial_states(params[:, COL["v_start"]], rng)
    a1, a2, sw = sample_control_schedules(n, HORIZON_S, rng)
    (_, py, _, _), _ = rk4_rollout(start, params, np.full(n, HORIZON_S), a1, a2, sw, 150)
    exact = support(extreme_point(v_start, w, a_hi, math.pi / 2, HORIZON_S), math.pi / 2)
    assert py.max() < exact - 3.0


@pytest.mark.parametrize("name", CASES)
def test_outer_bound_contains_the_exact_front(name: str) -> None:
    v_start, w, a_lo, a_hi = _bounds(name)
    ob = outer_bound(v_start, _bound_columns(w, a_lo, a_hi), steps=120)
    polygon = shapely.Polygon(ob.polygons_at([len(ob.times) - 1])[0])
    for phi in PHIS:
        p = extreme_point(v_start, w, a_hi, phi, HORIZON_S)
        assert polygon.buffer(1e-6).contains(shapely.Point(*p)), f"phi={phi:.2f}"


@pytest.mark.skipif(not MODEL.exists(), reason="no shipped model yet")
@pytest.mark.parametrize("name", CASES)
def test_served_tube_contains_the_exact_front(name: str) -> None:
    """Under-approximation is the failure that matters: the front points, reached at 1, 2 and 3 s,
    lie in the service's tube up to that time."""
    from models.runtime import ValueModel
    from models.value_fields import engine_for
    from reach.frames import Pose

    engine = engine_for(ValueModel.load(MODEL))
    v_start, w, a_lo, a_hi = _bounds(name)
    frt = engine.exact(Pose(0.0, 0.0, 0.0), v_start, _bound_columns(w, a_lo, a_hi))
    for t_end in (1.0, 2.0, 3.0):
        tube = frt.geometry("tube", t_end).buffer(1e-6)
        for phi in PHIS:
            p = extreme_point(v_start, w, a_hi, phi, t_end)
            assert tube.contains(shapely.Point(*p)), f"t={t_end} phi={phi:.2f} point {p}"
