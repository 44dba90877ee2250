"""The corridor lower bound on V: never above the value of a simulated state, and not vacuous
where the interval outer bound is (the notch behind a car)."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import shapely

from models.bounded_states import sample_bounded_states
from models.eval_settings import SETTINGS
from models.rollout import (
    sample_control_schedules,
    sample_reference_schedules,
)
from models.sampling import sample_parameters
from reach.contract import COL, HORIZON_S, N_INPUTS
from reach.corridors import value_lower_bound
from reach.dynamics import initial_set_value
from reach.outer_bound import outer_bound
from tests.fixtures.trajectories import simulate


def _inputs(t: float, state: tuple[np.ndarray, ...], v_start: float, bounds: np.ndarray):
    x = np.zeros((len(state[0]), N_INPUTS))
    x[:, COL["t"]] = t
    x[:, COL["px"]], x[:, COL["py"]] = state[0], state[1]
    x[:, COL["heading"]] = (state[2] + np.pi) % (2 * np.pi) - np.pi
    x[:, COL["speed"]] = state[3]
    x[:, COL["v_start"]] = v_start
    x[:, 6:] = bounds
    return x


@pytest.mark.parametrize(
    ("seed", "schedules"), [(0, sample_control_schedules), (1, sample_reference_schedules)]
)
def test_the_bound_never_exceeds_the_initial_value_of_a_simulated_state(seed, schedules) -> None:
    """V(t, xi(t)) <= l(xi(0)) for every trajectory, so a sound lower bound must be below l(xi(0)):
    starts spread over three times the initial set (l up to ~1 m), edge starts, all settings
    of every third evaluation setting and random in-range ones, several times."""
    rng = np.random.default_rng(seed)
    settings = [(s.v_start, s.bounds()) for s in SETTINGS[seed::3]]
    settings += [(float(p[COL["v_start"]]), p[6:]) for p in sample_parameters(4, rng)]
    n = 300
    for v_start, bounds in settings:
        start, trace = simulate(v_start, bounds, n, rng, schedules, spread=3.0, on_boundary=0.3)
        initial_value = initial_set_value(*start, v_start)
        for tau, state in trace[14::45]:
            bound = value_lower_bound(_inputs(float(tau[0]), state, v_start, bounds))
            assert np.all(bound < np.maximum(initial_value, 0.0) + 1e-9), (v_start, bounds)


def test_it_excludes_the_notch_behind_a_car_inside_the_outer_polygon() -> None:
    """urban_wide (8 m/s, |u1| <= 1.2, |u2| <= 6) at t = 3 s: 10 m straight behind the start lies
    inside the convex outer polygon, yet no heading and speed make it reachable."""
    setting = {s.name: s for s in SETTINGS}["urban_wide"]
    bounds = setting.bounds()
    ob = outer_bound(setting.v_start, bounds)
    row = int(np.argmin(np.abs(ob.times - HORIZON_S)))
    assert shapely.Polygon(ob.polygons_at([row])[0]).contains(shapely.Point(-10.0, 0.0))
    headings = np.linspace(-np.pi, np.pi, 48, endpoint=False)
    speeds = np.linspace(*ob.speed[row], 12)
    h, v = (a.ravel() for a in np.meshgrid(headings, speeds))
    state = (np.full(h.size, -10.0), np.zeros(h.size), h, v)
    bound = value_lower_bound(_inputs(HORIZON_S, state, setting.v_start, bounds))
    assert bound.min() > 0.5


def test_training_states_carry_their_bound() -> None:
    x, bound = sample_bounded_states(4, 32, np.random.default_rng(0))
    assert len(x) > 32 and np.all(bound >= 0)
    np.testing.assert_array_equal(value_lower_bound(x), bound)


def _settings(names: tuple[str, ...], n_random: int, rng: np.random.Generator) -> list:
    """(v_start, bounds) of the named evaluation settings, then of ``n_random`` random ones."""
    named = {s.name: s for s in SETTINGS}
    settings = [(named[name].v_start, named[name].bounds()) for name in names]
    return settings + [(float(p[COL["v_start"]]), p[6:]) for p in sample_parameters(n_random, rng)]


def _assert_bins_hold_simulated_positions(
    settings: list, schedules, rng: np.random.Generator, every: slice, partition
) -> None:
    """At the recorded times ``every`` picks, the union of the bin polygons ``partition(v_start,
    bounds, times)`` gives (supports [J, B, M] in DIRECTIONS, empty [J, B]) contains the position
    of every one of 2000 simulated trajectories."""
    from reach.corridors import DIRECTIONS

    normals = np.stack([np.cos(DIRECTIONS), np.sin(DIRECTIONS)])
    for v_start, bounds in settings:
        _, trace = simulate(v_start, bounds, 2000, rng, schedules)
        picked = trace[every]
        times = np.array([float(tau[0]) for tau, _ in picked])
        support, empty = partition(v_start, bounds, times)
        for j, (_, state) in enumerate(picked):
            reach = np.stack([state[0], state[1]], axis=1) @ normals  # [n, M]
            inside = np.all(reach[:, None, :] <= support[j][None] + 1e-9, axis=2) & ~empty[j]
            assert inside.any(axis=1).all(), (v_start, bounds, times[j])


@pytest.mark.parametrize("seed", [0, 1])
def test_partition_polygons_hold_every_simulated_position(seed: int) -> None:
    """The union of a time's heading x speed bin polygons (reach.corridors.partition_supports)
    contains the position of every trajectory from the initial set at that time: wide, shrinking
    and random settings, switching and extremal schedules, edge starts."""
    from reach.partition import partition_supports

    rng = np.random.default_rng(seed)
    names = ("urban_wide", "shrinking_wide_to_narrow", "growing_narrow_to_wide")
    _assert_bins_hold_simulated_positions(
        _settings(names, 3, rng),
        (sample_control_schedules, sample_reference_schedules)[seed],
        rng,
        slice(29, None, 40),
        lambda v_start, bounds, times: partition_supports(v_start, bounds, times, 12, 4),
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_speed_coupled_polygons_hold_every_simulated_position(seed: int) -> None:
    """With the speed coupled over time (reach.speed_programme: one linear programme per bin and
    direction), the union of a time's bin polygons still contains the position of every trajectory
    at that time: wide, shrinking, forced braking (u2 < 0 throughout), forced acceleration late
    (u2 > 0 at the end) and random settings; switching and extremal schedules, edge starts."""
    from reach.partition import partition_supports

    rng = np.random.default_rng(seed)
    names = (
        ("urban_wide", "braking_hard", "stop_sign_runner"),
        ("shrinking_wide_to_narrow", "braking_to_stop", "u_turn_like"),
    )[seed]
    _assert_bins_hold_simulated_positions(
        _settings(names, 2, rng),
        (sample_control_schedules, sample_reference_schedules)[seed],
        rng,
        slice(44, None, 50),
        lambda v_start, bounds, times: partition_supports(
            v_start, bounds, times, 8, 2, coupled_speed=True
        ),
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_waypoint_bins_hold_every_simulated_position_and_cut_the_notch_walls(seed: int) -> None:
    """Bins split again by the heading at a waypoint early in [0, t] (``waypoint_bins``; two
    waypoints in turn for seed 1): the union of a time's polygons still contains the position of
    every trajectory at that time (wide, shrinking, fast and random settings; switching and
    extremal schedules, edge starts), and at 3 s it is smaller than without the split where
    steering bounds shrink from wide."""
    from reach.corridors import DIRECTIONS
    from reach.partition import bins_union, partition_supports

    rng = np.random.default_rng(seed)
    names = (("shrinking_steering_only", "urban_wide"), ("fast_wide_limits", "left_turn"))[seed]
    _assert_bins_hold_simulated_positions(
        _settings(names, 2, rng),
        (sample_reference_schedules, sample_control_schedules)[seed],
        rng,
        slice(34, None, 40),
        lambda v_start, bounds, times: partition_supports(
            v_start,
            bounds,
            times,
            8,
            1,
            steps=30,
            coupled_speed=True,
            # one waypoint, or two in turn (each splitting the interval its bin leaves)
            waypoint_bins=(6, (4, 3))[seed],
            waypoint_at=(0.2, (0.2, 0.5))[seed],
        ),
    )
    named = {s.name: s for s in SETTINGS}
    shrinking = named["shrinking_steering_only"]
    areas = [
        bins_union(
            *(a[0] for a in partition_supports(
                shrinking.v_start, shrinking.bounds(), np.array([3.0]), 8, 1, steps=30,
                coupled_speed=True, waypoint_bins=w,
            )),
            DIRECTIONS,
        ).area
        for w in (1, 6)
    ]  # fmt: skip
    assert areas[1] < areas[0] - 20.0  # m²


def test_partition_tubes_hold_every_simulated_position_up_to_their_time() -> None:
    """reach.corridors.partition_tubes (the evaluation's proven outer tube): every position
    recorded every 0.02 s, between the 0.1 s instants too, lies in the tube of each t_end after
    it; a wide, a shrinking and a random setting, extremal schedules, edge starts."""
    from reach.partition import partition_tubes

    rng = np.random.default_rng(5)
    named = {s.name: s for s in SETTINGS}
    settings = [
        (named[name].v_start, named[name].bounds())
        for name in ("urban_wide", "shrinking_steering_only")
    ]
    settings += [(float(p[COL["v_start"]]), p[6:]) for p in sample_parameters(1, rng)]
    t_ends = (1.0, 3.0)
    for v_start, bounds in settings:
        speed_max = float(outer_bound(v_start, bounds).sweep_speed_max.max())
        coarse = functools.partial(
            partition_tubes, v_start, bounds, t_ends, speed_max, 8, steps=20
        )  # 8 heading bins, 20 sub-intervals, and:
        variants = (
            partition_tubes(v_start, bounds, t_ends, speed_max),
            # heading waypoint bins, one waypoint and two
            coarse(waypoint_bins=4),
            coarse(waypoint_bins=(3, 2), waypoint_at=(0.2, 0.5)),
            # the cheap variant: convex polygons up to 1.5 s
            coarse(partitioned_from_s=1.5),
            # finer: 24 directions, instants 0.05 s apart
            coarse(instant_s=0.05, directions=np.arange(24) * (2 * np.pi / 24)),
        )
        _, trace = simulate(v_start, bounds, 1000, rng, sample_reference_schedules)
        for tau, state in trace[::3]:
            points = shapely.points(np.stack([state[0], state[1]], axis=1))
            for tubes in variants:
                for t_end, tube in zip(t_ends, tubes, strict=True):
                    if float(tau[0]) <= t_end + 1e-9:
                        assert shapely.covers(tube, points).all(), (v_start, float(tau[0]), t_end)


def test_coupling_the_speed_cuts_where_independent_speed_ends_do_not() -> None:
    """urban_wide at t = 3 s, 14 m behind and 4 m beside the start: inside a 16 x 6 heading x
    speed bin polygon with the speed's ends taken independently at every instant, outside all 16
    heading bin polygons with the speed coupled (to be fast while heading backwards the car must
    have kept its speed while it headed forwards, and moved forwards)."""
    from reach.corridors import DIRECTIONS
    from reach.partition import partition_supports

    setting = {s.name: s for s in SETTINGS}["urban_wide"]
    point = np.array([-14.0, 4.0]) @ np.stack([np.cos(DIRECTIONS), np.sin(DIRECTIONS)])
    loose, loose_empty = partition_supports(setting.v_start, setting.bounds(), [HORIZON_S], 16, 6)
    assert (np.all(point[None, :] <= loose[0], axis=1) & ~loose_empty[0]).any()
    tight, tight_empty = partition_supports(
        setting.v_start, setting.bounds(), [HORIZON_S], 16, 1, coupled_speed=True
    )
    assert not (np.all(point[None, :] <= tight[0], axis=1) & ~tight_empty[0]).any()


def test_partition_polygons_cut_into_the_notch_the_convex_polygon_covers() -> None:
    """urban_wide at t = 3 s: 20 m behind the start is inside the convex outer polygon and outside
    every one of 16 x 6 heading x speed bin polygons."""
    from reach.corridors import DIRECTIONS
    from reach.partition import partition_supports

    setting = {s.name: s for s in SETTINGS}["urban_wide"]
    ob = outer_bound(setting.v_start, setting.bounds())
    row = int(np.argmin(np.abs(ob.times - HORIZON_S)))
    behind = np.array([-20.0, 0.0])
    assert shapely.Polygon(ob.polygons_at([row])[0]).contains(shapely.Point(*behind))
    support, empty = partition_supports(setting.v_start, setting.bounds(), [HORIZON_S], 16, 6)
    reach = behind @ np.stack([np.cos(DIRECTIONS), np.sin(DIRECTIONS)])
    assert not (np.all(reach[None, :] <= support[0], axis=1) & ~empty[0]).any()


def test_positions_the_projection_is_lifted_at_are_unreachable_for_every_heading_and_speed() -> (
    None
):
    """models.projection.unreachable_xy keeps positions no bin polygon holds; the per-state bound
    (final heading and speed pinned, a tighter corridor) must then exclude them at every heading
    and speed on a grid, and they lie inside the convex outer polygon (where the cut matters)."""
    from models.projection import unreachable_xy

    rows, scale = unreachable_xy(60, 128, 0.05, np.random.default_rng(2))
    assert len(rows) > 20 and np.all(scale > 0)
    pick = rows[:: max(len(rows) // 12, 1)][:12]
    headings = np.linspace(-np.pi, np.pi, 24, endpoint=False)
    for row in pick:
        ob = outer_bound(float(row[COL["v_start"]]), row[6:])
        k = int(np.argmin(np.abs(ob.times - row[COL["t"]])))
        point = shapely.Point(float(row[COL["px"]]), float(row[COL["py"]]))
        assert shapely.Polygon(ob.polygons_at([k])[0]).buffer(1e-6).contains(point)
        speeds = np.linspace(*ob.speed[k], 8)
        h, v = (a.ravel() for a in np.meshgrid(headings, speeds))
        x = np.repeat(row[None].astype(float), h.size, axis=0)
        x[:, COL["heading"]], x[:, COL["speed"]] = h, v
        assert value_lower_bound(x).min() >= 0.0


@pytest.mark.parametrize("seed", [0, 1])
def test_a_swept_bin_holds_every_short_path_from_it(seed: int) -> None:
    """``swept_supports``: from any point of a bin's polygon, a path of at most ``reach`` metres
    (either way in time) whose heading stays within the bin's headings widened by ``turn`` ends
    inside the swept polygon, and inside the half swept that way in time alone (``before`` /
    ``after``); and sweeping is thinner than growing by a disc across the headings."""
    from reach.corridors import DIRECTIONS
    from reach.partition import swept_supports
    from reach.polygons import half_plane_polygons

    rng = np.random.default_rng(seed)
    for _ in range(20):
        lo = rng.uniform(-4.0, 4.0)
        headings = np.array([[lo, lo + rng.uniform(0.0, 1.5)]])
        reach, turn = rng.uniform(0.1, 2.0), rng.uniform(0.0, 0.2)
        box = shapely.box(*sorted(rng.uniform(-3, 3, 2)), *sorted(rng.uniform(4, 9, 2)))
        support = np.array([[max(np.cos(a) * x + np.sin(a) * y for x, y in box.exterior.coords)
                             for a in DIRECTIONS]])  # fmt: skip
        swept = swept_supports(support, headings, reach, turn)
        polygon = shapely.Polygon(half_plane_polygons(DIRECTIONS, swept)[0])
        halves = {  # the sign of time: +1 after the instant, -1 before it
            sign: shapely.Polygon(
                half_plane_polygons(
                    DIRECTIONS,
                    swept_supports(support, headings, reach, turn, before=sign < 0, after=sign > 0),
                )[0]
            )
            for sign in (-1.0, 1.0)
        }
        starts = shapely.get_coordinates(box.exterior)[:-1]
        for start in starts:
            steps = 50
            theta = np.clip(
                rng.uniform(headings[0, 0], headings[0, 1]) + np.cumsum(rng.normal(0, 0.1, steps)),
                headings[0, 0] - turn,
                headings[0, 1] + turn,
            )
            speed = rng.uniform(0.0, 1.0, steps) * reach / steps
            moves = np.stack([np.cos(theta), np.sin(theta)], axis=1) * speed[:, None]
            sign = rng.choice([-1.0, 1.0])  # after the instant, or (backwards) before it
            ends = start + sign * np.cumsum(moves, axis=0)
            assert shapely.covers(polygon.buffer(1e-9), shapely.points(ends)).all()
            assert shapely.covers(halves[sign].buffer(1e-9), shapely.points(ends)).all()
        disc = shapely.Polygon(half_plane_polygons(DIRECTIONS, support + reach)[0])
        assert polygon.area <= disc.area + 1e-9
        assert halves[-1.0].area < polygon.area and halves[1.0].area < polygon.area
