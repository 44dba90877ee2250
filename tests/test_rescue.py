"""experiments.sensor_tracks and experiments.rescue without the replay: the motion estimates, the
wrong predictor, the halves and the summary arithmetic."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from experiments import av2, rescue, sensor_tracks
from experiments.rescue import Observation, Run
from experiments.sensor_tracks import ClassedTrack

DT = av2.SAMPLE_DT_S


def _track(t: np.ndarray, heading: np.ndarray, speed: np.ndarray, tid: str = "t") -> av2.Track:
    """A unicycle track integrated from its heading and speed (positions by the midpoint rule)."""
    x = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.cos(heading[:-1]) * np.diff(t))])
    y = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.sin(heading[:-1]) * np.diff(t))])
    return av2.Track(tid, t, x, y, heading, speed)


def test_straight_line_with_noise_gives_its_speed_and_heading() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(80) * DT
    speed, heading = 7.0, 2.5
    x = 10.0 + speed * t * math.cos(heading) + rng.normal(0, 0.03, t.size)
    y = -4.0 + speed * t * math.sin(heading) + rng.normal(0, 0.03, t.size)
    h, v = sensor_tracks.estimate_motion(x, y)
    assert np.all(np.abs(v - speed) < 0.15)
    assert np.all(np.abs(np.angle(np.exp(1j * (h - heading)))) < 0.03)


def test_circle_gives_its_speed_and_a_continuous_heading() -> None:
    rng = np.random.default_rng(1)
    radius, speed = 12.0, 6.0
    omega = speed / radius
    t = np.arange(150) * DT  # 15 s: 7.5 rad, more than a full turn
    phase = omega * t
    x = radius * np.sin(phase) + rng.normal(0, 0.02, t.size)
    y = radius * (1 - np.cos(phase)) + rng.normal(0, 0.02, t.size)
    h, v = sensor_tracks.estimate_motion(x, y)
    inner = slice(5, -5)
    assert np.all(np.abs(v[inner] - speed) < 0.1)
    # unwrapped: follows phase past 2 pi with no jump of 2 pi
    assert np.max(np.abs(h[inner] - phase[inner])) < 0.03
    assert np.max(np.abs(np.diff(h))) < 0.1
    rate = np.diff(h[inner]) / DT
    assert abs(float(np.mean(rate)) - omega) < 0.01


def test_a_stop_holds_the_last_motion_heading_and_a_parked_track_its_yaw() -> None:
    # east at 5 m/s for 3 s, then still for 3 s
    t = np.arange(60) * DT
    x = np.where(t < 3.0, 5.0 * t, 15.0)
    y = np.zeros_like(t)
    h, v = sensor_tracks.estimate_motion(x, y)
    assert np.all(np.abs(h) < 1e-6)
    assert np.all(v[-10:] < 0.01)
    # never moving: the box yaw most samples agree with, though two are flipped by pi
    yaw = np.full(t.size, 1.0)
    yaw[[3, 17]] += math.pi
    h, _ = sensor_tracks.estimate_motion(np.full(t.size, 2.0), np.full(t.size, 3.0), yaw=yaw)
    assert np.allclose(h, 1.0)


def test_flipped_box_yaws_are_counted_not_used() -> None:
    t = np.arange(50) * DT
    x, y = 4.0 * t, np.zeros_like(t)
    yaw = np.zeros_like(t)
    yaw[10:15] = math.pi  # the box turned round, the car did not
    h, v = sensor_tracks.estimate_motion(x, y, yaw=yaw)
    assert np.allclose(h, 0.0, atol=1e-6)
    assert sensor_tracks.yaw_flips(yaw, h, v) == 5


def test_sensor_loader_reads_classes_and_drops_short_tracks(tmp_path: Path) -> None:
    k = list(range(100, 150))
    tracks = [
        {"log": "abcdefgh-1", "track_uuid": "u1", "category": "PEDESTRIAN",
         "agent_class": "pedestrian", "k": k, "x": [1.2 * 0.1 * i for i in range(50)],
         "y": [0.0] * 50, "yaw": [0.0] * 50},
        {"log": "abcdefgh-1", "track_uuid": "u2", "category": "REGULAR_VEHICLE",
         "agent_class": "car", "k": k[:30], "x": [0.0] * 30, "y": [0.0] * 30, "yaw": [0.0] * 30},
    ]  # fmt: skip
    path = tmp_path / "tracks.json"
    path.write_text(json.dumps({"tracks": tracks}))
    loaded = sensor_tracks.load_sensor(path)
    assert [(c.track_id, c.agent_class, c.source) for c in loaded] == [
        ("abcdefgh-u1", "pedestrian", "sensor")
    ]
    track = loaded[0].track
    assert track.t[0] == pytest.approx(10.0) and track.duration_s == pytest.approx(4.9)
    assert np.allclose(track.speed, 1.2, atol=1e-6)


def test_wrong_mean_is_against_the_actual_controls() -> None:
    t = np.arange(60) * DT
    for sign in (1.0, -1.0):
        # turning at 0.3 sign rad/s and accelerating at 1.5 sign m/s^2
        heading = 0.3 * sign * t
        speed = 8.0 + 1.5 * sign * t
        track = _track(t, heading, speed)
        i = 10
        actual = track.future_actions(i).mean(axis=0)
        assert np.sign(actual[0]) == sign and np.sign(actual[1]) == sign
        wrong = rescue.wrong_mean(track, i, "car")
        assert wrong.shape == (av2.STEPS, 2)
        assert np.allclose(wrong, [-0.2 * sign, -3.0 * sign])
        # the right one follows the turn
        assert np.allclose(rescue.right_mean(track, i, "car"), [0.3 * sign, 0.0], atol=1e-9)
    # straight at constant speed: sign 0 counts as +
    still = _track(t, np.zeros_like(t), np.full_like(t, 5.0))
    assert np.allclose(rescue.wrong_mean(still, 10, "pedestrian"), [-0.2, -3.0])


def test_means_are_clipped_to_the_class_limits() -> None:
    mean = np.tile([5.0, -12.0], (av2.STEPS, 1))
    assert np.allclose(rescue.clip_mean(mean, "pedestrian"), [4.0, -3.0])
    assert np.allclose(rescue.clip_mean(mean, "car"), [2.0, -10.0])


def test_the_predictor_turns_wrong_at_the_switch() -> None:
    t = 3.0 + np.arange(60) * DT
    track = _track(t, np.zeros_like(t), np.full_like(t, 5.0))
    wrong, right = Run("wrong", True), Run("right", True)
    obs = rescue.observed_indices(track, switch_s=1.0, after_s=2.0)
    assert [round(track.t[i] - t[0], 3) for i in obs] == [0.5, 1.0, 1.5, 2.0, 2.5]
    assert [rescue.is_wrong(wrong, track, i, 1.0) for i in obs] == [False, True, True, True, True]
    assert not any(rescue.is_wrong(right, track, i, 1.0) for i in obs)


def test_halves_never_share_a_track_and_alternate_per_class() -> None:
    tracks = sensor_tracks.load_all()
    split = rescue.halves(tracks)
    cal = {c.track_id for c in split["calibration"]}
    held = {c.track_id for c in split["held_out"]}
    assert not cal & held
    assert cal | held == {c.track_id for c in tracks}
    for klass, group in sensor_tracks.by_class(tracks).items():
        ids = sorted(c.track_id for c in group)
        assert {i for i in ids[0::2]} <= cal, klass
        assert {i for i in ids[1::2]} <= held, klass


def test_run_config_sends_the_rule_only_when_asked() -> None:
    paper = Run("right", True).config("pedestrian")
    assert paper == {"beta_low": 0.03, "gamma": 0.075, "collision_radius": 0.75}
    mixed = Run("wrong", False, "uniform_mixture", rescue.uniform_onsets(0.25)).config("car")
    assert mixed["bounds_rule"] == "uniform_mixture" and mixed["rescue_onset"] == 0.25
    assert mixed["beta_low"] == pytest.approx(1 - 1e-6) and mixed["collision_radius"] == 1.5
    assert Run("wrong", True, "mass_ramp", rescue.uniform_onsets(0.5)).label == (
        "wrong/on/mass_ramp@0.5"
    )


def test_score_future_counts_from_half_a_second() -> None:
    ahead = np.arange(1, 31) * DT
    clearance = np.zeros(30)
    clearance[0] = 9.0  # +0.1 s: not counted
    clearance[10] = 2.0  # +1.1 s: 0.5 m outside R_col = 1.5
    clearance[-1] = 1.5  # +3 s: on the boundary, inside
    share, end, worst = rescue.score_future(clearance, ahead, 1.5)
    assert share == pytest.approx(25 / 26)
    assert end is True
    assert worst == pytest.approx(0.5)


def _obs(tid: str, since: float, speed: float, beta: float, in_c: float, area: float,
         end: bool = True, worst: float = -1.0) -> Observation:  # fmt: skip
    return Observation(tid, "car", 1.0 + since, since, speed, beta, in_c, end, worst, area, False)


def test_summary_arithmetic() -> None:
    rows = [
        _obs("a", -0.5, 5.0, 0.9, 0.0, 1000.0),  # before the switch: ignored
        _obs("a", 0.0, 5.0, 0.8, 1.0, 10.0),
        _obs("a", 0.5, 5.0, 0.6, 0.5, 20.0, end=False, worst=2.5),
        _obs("a", 1.0, 5.0, 0.3, 1.0, 30.0),
        _obs("b", 0.0, 0.2, 0.7, 0.0, 40.0, end=False, worst=7.0),  # not moving
        _obs("b", 0.5, 3.0, 0.45, 0.75, 50.0),
        _obs("c", 0.0, 2.0, 0.9, 1.0, 60.0),
    ]
    s = rescue.summarise(rows, moving_speed=1.0)
    moving = [1.0, 0.5, 1.0, 0.75, 1.0]
    assert s["observations"] == 6 and s["moving_observations"] == 5 and s["tracks"] == 3
    assert s["coverage_c"] == pytest.approx(round(sum(moving) / 5, 4))
    assert s["coverage_c_3s"] == pytest.approx(0.8)
    assert s["coverage_c_every_observation"] == pytest.approx(round(4.25 / 6, 4))
    assert s["worst_outside_c_m"] == pytest.approx(2.5)
    assert s["mean_area_c_m2"] == pytest.approx(35.0)
    assert s["mean_area_c_moving_m2"] == pytest.approx(34.0)
    assert s["mean_beta"] == pytest.approx(round((0.8 + 0.6 + 0.3 + 0.7 + 0.45 + 0.9) / 6, 4))
    # a: beta < 0.5 two observations after the switch; b: one after; c: never
    assert s["until_beta_below_half"] == {"median": 1.5, "max": 2, "tracks": 3, "never": 1}
    curve = {p["since_switch_s"]: p for p in rescue.by_time(rows, 1.0)}
    assert sorted(curve) == [0.0, 0.5, 1.0]
    assert curve[0.0]["coverage_c"] == pytest.approx(1.0)
    assert curve[0.0]["mean_area_c_m2"] == pytest.approx(110.0 / 3, abs=0.01)
    assert curve[0.5]["coverage_c"] == pytest.approx(0.625)


def test_all_inside_has_no_distance_outside() -> None:
    s = rescue.summarise([_obs("a", 0.0, 5.0, 0.9, 1.0, 1.0, worst=-0.3)], moving_speed=1.0)
    assert s["worst_outside_c_m"] == 0.0


def _grid_figs(rows: dict[float, tuple[float | None, float]]) -> dict:
    figs: dict = {}
    for onset, (wrong_cov, right_area) in rows.items():
        figs[f"wrong/on/uniform_mixture@{onset:g}"] = {
            "calibration": {"car": {"coverage_c": 0.5, "coverage_c_informed": wrong_cov}}
        }
        figs[f"right/on/uniform_mixture@{onset:g}"] = {
            "calibration": {"car": {"mean_area_c_m2": right_area}}
        }
    return figs


def test_onset_choice_smallest_area_among_those_reaching_the_goal() -> None:
    figs = _grid_figs({0.0: (0.999, 90.0), 0.25: (0.995, 70.0), 0.5: (0.98, 60.0)})
    c = rescue.choose_onset(figs, "uniform_mixture", "car", [0.0, 0.25, 0.5])
    assert c["onset"] == 0.25 and c["reached"]
    figs = _grid_figs({0.0: (0.97, 90.0), 0.25: (0.98, 70.0), 0.5: (0.98, 60.0)})
    c = rescue.choose_onset(figs, "uniform_mixture", "car", [0.0, 0.25, 0.5])
    assert c["onset"] == 0.5 and not c["reached"]
    figs = _grid_figs({0.0: (None, 90.0), 0.25: (0.9, 70.0)})
    c = rescue.choose_onset(figs, "uniform_mixture", "car", [0.0, 0.25])
    assert c["onset"] == 0.25 and not c["reached"]


def test_classed_track_id() -> None:
    t = np.arange(45) * DT
    ct = ClassedTrack(_track(t, np.zeros_like(t), np.ones_like(t), "x1"), "cyclist", "sensor")
    assert ct.track_id == "x1"
