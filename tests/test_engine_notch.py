"""engine_for(model, notch_cut=True): exact sets also cut to the speed-coupled partition where the car may
head backwards. The cut must keep every simulated position the uncut set holds (tubes up to each
time, slices at the instants, intervals between them), stay inside the uncut set, and cut."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

from models.eval_settings import SETTINGS
from models.rollout import sample_reference_schedules
from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.engine import FRTEngine
from reach.frames import Pose
from reach.notch import NOTCH_STAGES
from tests.fixtures.trajectories import simulate

MODEL = Path(__file__).resolve().parent.parent / "models" / "frt_unicycle.onnx"
NAMED = {s.name: s for s in SETTINGS}


@pytest.fixture(scope="module")
def engines() -> tuple[FRTEngine, FRTEngine]:
    model = ValueModel.load(MODEL, threads=1)
    return engine_for(model), engine_for(model, notch_cut=True)


def _covered(geometry: shapely.Geometry, state: tuple[np.ndarray, ...]) -> np.ndarray:
    return shapely.covers(geometry, shapely.points(np.stack([state[0], state[1]], axis=1)))


@pytest.mark.parametrize("stage", range(1, len(NOTCH_STAGES) + 1))
@pytest.mark.parametrize("name", ["urban_wide", "shrinking_steering_only"])
def test_the_cut_keeps_every_simulated_position_and_cuts(engines, name: str, stage: int) -> None:
    plain, notched = engines
    setting = NAMED[name]
    bounds = setting.bounds()
    uncut = plain.exact(Pose(0.0, 0.0, 0.0), setting.v_start, bounds)
    cut = notched.exact(Pose(0.0, 0.0, 0.0), setting.v_start, bounds, notch_stage=stage)
    assert cut.notch is not None and cut.notch.stage == stage
    last = cut.n_slices - 1
    assert cut.tube(last).difference(uncut.tube(last)).area < 1e-6
    assert uncut.tube(last).area - cut.tube(last).area > 50.0  # m²: it cuts the notch
    _, trace = simulate(setting.v_start, bounds, 1500, np.random.default_rng(11),
                        sample_reference_schedules)  # fmt: skip
    per_instant = round(cut.slice_dt / float(trace[0][0][0]))  # recorded steps per instant
    for k, (tau, state) in enumerate(trace, start=1):
        s = float(tau[0])
        j = cut.tube_index(s)
        assert not (_covered(uncut.tube(j), state) & ~_covered(cut.tube(j), state)).any(), (s, j)
        if k % per_instant == 0:  # an instant: its slice
            i = k // per_instant
            assert not (_covered(uncut.slice(i), state) & ~_covered(cut.slice(i), state)).any()
        elif k % 7 == 0:  # between instants: the interval that holds it
            i = k // per_instant + 1
            assert not (
                _covered(uncut.interval(i), state) & ~_covered(cut.interval(i), state)
            ).any(), (s, i)


def test_a_set_that_cannot_turn_round_is_not_cut(engines) -> None:
    plain, notched = engines
    setting = NAMED["urban_narrow"]
    uncut = plain.exact(Pose(0.0, 0.0, 0.0), setting.v_start, setting.bounds())
    cut = notched.exact(Pose(0.0, 0.0, 0.0), setting.v_start, setting.bounds())
    assert cut.notch is None
    assert cut.tube(cut.n_slices - 1).equals(uncut.tube(uncut.n_slices - 1))


def test_worker_processes_cut_as_the_server_engine_does(engines) -> None:
    """A task that asks for the cut (``ExactTask(notch_cut=True)``, the service's refinement) is
    cut in a worker process as by the server's own engine, and comes back with every tube drawn but
    without the cut's regions (rebuilt on demand for slices, not kept for the garbage collector
    to walk)."""
    from service.runtime.exact_worker import ExactTask, start_pool

    plain, _ = engines
    setting = NAMED["urban_wide"]
    pool = start_pool(MODEL, workers=1, nice=0)
    try:
        task = ExactTask(Pose(4.0, -1.0, 0.3), setting.v_start, setting.bounds(), plain, True)
        there = pool.submit(task).result(timeout=120)
    finally:
        pool.shutdown()
    here = task()
    assert there.notch is not None and len(there._notch_regions) == 0 == len(there._notch_tubes)
    assert there.missing_tubes(list(range(there.n_slices))) == []
    for j in (there.n_slices - 1, 17):
        assert there.tube(j).equals(here.tube(j))
    assert there.slice(25).equals(here.slice(25))
