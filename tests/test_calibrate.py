"""``make calibrate`` (experiments/calibrate.py) on synthetic tracks through a real local service.

The synthetic cars drive at 5 m/s and steer at a rate drawn afresh every 0.5 s, so the predictor
(constant velocity and turn rate) is wrong by a fitted amount and a small gamma's sets miss; both
halves come from the same process, so the gamma chosen on one half should hold on the other.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from experiments import av2, calibrate, track_files
from experiments.server import connect
from service.runtime.profiles import ProfileError, load_profile, write_profile
from service.runtime.settings import Settings

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

TARGET = 0.95
GAMMAS = (0.05, 0.5, 0.99)


def synthetic_tracks(n: int, seconds: float = 6.0, sd: float = 0.35, seed: int = 7) -> list:
    """``n`` cars at 10 Hz steering at a rate drawn from N(0, sd^2) every 0.5 s."""
    rng = np.random.default_rng(seed)
    tracks = []
    steps = round(seconds / av2.SAMPLE_DT_S) + 1
    for k in range(n):
        x, y, h, v = 0.0, 10.0 * k, float(rng.uniform(-math.pi, math.pi)), 5.0
        rows = []
        u1 = 0.0
        for i in range(steps):
            if i % 5 == 0:
                u1 = float(rng.normal(0.0, sd))
            rows.append((i * av2.SAMPLE_DT_S, x, y, h, v))
            for _ in range(10):  # 0.01 s substeps of the unicycle
                x, y, h = x + v * math.cos(h) * 0.01, y + v * math.sin(h) * 0.01, h + u1 * 0.01
        a = np.array(rows)
        tracks.append(av2.Track(f"syn{k:02d}", a[:, 0], a[:, 1], a[:, 2], a[:, 3], a[:, 4]))
    return tracks


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory, analytic_model_path: Path) -> Iterator[object]:
    log = tmp_path_factory.mktemp("calibrate") / "service.log"
    with connect(None, analytic_model_path, log) as c:
        yield c


def test_calibration_picks_a_gamma_whose_held_out_coverage_meets_the_target(
    client: object, tmp_path: Path
) -> None:
    tracks = synthetic_tracks(12)
    result = calibrate.calibrate(client, tracks, GAMMAS, TARGET, beta_lows=(0.03,), log=print)
    points, choice = result["points"], result["choice"]
    assert choice["target_reached"]
    chosen = choice["chosen"]
    gamma = choice["per_confidence"][chosen]["gamma"]
    calib = {
        p.gamma: p.coverage_c for p in points if p.confidence == chosen and p.half == "calibration"
    }
    # The smallest gamma reaching the target on the calibration half, and a choice that matters.
    assert calib[gamma] >= TARGET
    assert all(c < TARGET for g, c in calib.items() if g < gamma)
    assert calib[min(GAMMAS)] < TARGET, "the smallest gamma must miss, or nothing was chosen"
    held = calibrate.point(points, chosen, gamma, "held_out")
    assert held.observations > 0
    assert held.coverage_c >= TARGET
    # Larger gamma, larger C.
    areas = [p.mean_area_c_m2 for p in sorted(points, key=lambda p: p.gamma)
             if p.confidence == chosen and p.half == "held_out"]  # fmt: skip
    assert areas == sorted(areas)

    settings = calibrate.profile_settings(result)
    path = write_profile(tmp_path / "syn.json", "syn", settings, target=TARGET)
    assert load_profile(str(path), known=set(Settings.model_fields)) == settings
    out = calibrate.plot(points, choice, tmp_path / "plot.png", "synthetic")
    assert out.stat().st_size > 1000


def test_server_loads_a_profile_under_the_environment(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = write_profile(tmp_path / "p.json", "p", {"gamma": 0.4, "beta_low": 0.1})
    monkeypatch.setenv("FRT_PROFILE", str(path))
    assert (Settings().gamma, Settings().beta_low) == (0.4, 0.1)
    monkeypatch.setenv("FRT_GAMMA", "0.2")
    assert Settings().gamma == 0.2  # the environment wins
    monkeypatch.delenv("FRT_GAMMA")
    monkeypatch.setenv("FRT_PROFILE", "av2")  # by name: profiles/av2.json, from make calibrate
    shipped = load_profile("av2")
    assert Settings().gamma == shipped["gamma"] and Settings().beta_low == shipped["beta_low"]
    write_profile(tmp_path / "bad.json", "bad", {"gama": 0.4})
    monkeypatch.setenv("FRT_PROFILE", str(tmp_path / "bad.json"))
    with pytest.raises(ProfileError, match="gama"):
        Settings()


def test_track_file_round_trip_and_resampling(tmp_path: Path) -> None:
    tracks = synthetic_tracks(2, seconds=4.5)
    loaded = track_files.load(track_files.write_csv(tmp_path / "t.csv", tracks))
    assert [t.track_id for t in loaded] == [t.track_id for t in tracks]
    for a, b in zip(tracks, loaded, strict=True):
        for name in ("t", "x", "y", "heading", "speed"):
            np.testing.assert_allclose(getattr(b, name), getattr(a, name), atol=1e-5)
    # 20 Hz input with a gap: resampled to 10 Hz, cut at the gap, the short piece dropped.
    t = np.concatenate([np.arange(0, 5.0001, 0.05), np.arange(7.0, 8.0001, 0.05)])
    rows = ["track_id,t,x,y,heading,speed"] + [
        f"a,{ti:.3f},{2 * ti:.4f},0,0,2" for ti in t
    ]  # fmt: skip
    (tmp_path / "g.csv").write_text("\n".join(rows) + "\n")
    (piece,) = track_files.load(tmp_path / "g.csv")
    assert piece.track_id == "a#0" and len(piece.t) == 51
    np.testing.assert_allclose(piece.x, 2 * piece.t, atol=1e-6)
    (tmp_path / "bad.csv").write_text("track_id,t,x,y\na,0,0,0\n")
    with pytest.raises(ValueError, match="missing columns"):
        track_files.load(tmp_path / "bad.csv")
