"""Which tubes the workers draw: the largest index an agent's checks needed, none before any."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from models.runtime import ValueModel
from models.value_fields import engine_for
from reach.frames import Pose
from service.runtime.exact_worker import ExactTask
from service.runtime.tube_demand import NO_TUBES, TubeDemand


def test_demand_is_the_largest_index_asked_and_forgets() -> None:
    demand = TubeDemand(size=2)
    assert demand.upto("a") == NO_TUBES
    demand.note("a", 12)
    demand.note("a", 5)  # a shorter trajectory later does not undraw what a longer one needs
    assert demand.upto("a") == 12
    demand.note("b", 0)
    demand.note("c", 3)  # beyond the size: the least recently noted agent goes
    assert demand.upto("a") == NO_TUBES and demand.upto("b") == 0 and demand.upto("c") == 3
    demand.forget("c")
    assert demand.upto("c") == NO_TUBES


def test_a_task_draws_its_tubes_before_it_returns(analytic_model_path: Path) -> None:
    engine = engine_for(ValueModel.load(analytic_model_path))
    bounds = np.array([-0.1, -1.0, -0.1, -1.0, 0.1, 1.0, 0.1, 1.0])
    for upto, missing_after in ((NO_TUBES, True), (7, True), (1_000_000, False)):
        frt = ExactTask(Pose(0.0, 0.0, 0.0), 5.0, bounds, engine, tubes_upto=upto)()
        every = list(range(frt.n_slices))
        drawn = [j for j in every if j not in frt.missing_tubes(every)]
        assert (len(drawn) < frt.n_slices) is missing_after
        if upto >= 0:
            assert set(range(min(upto, frt.n_slices - 1) + 1)) <= set(drawn)
