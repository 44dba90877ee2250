"""Issue 8: each case study, shortened, in closed loop through a real service and the SDK.

Paper, section "Case Studies": with confidence the ego detects the conflict early and stops
safely; without, it detects late and collides. The run is shortened: no contours are fetched and
the loop ends as soon as the ego has stopped (the rest of the ground truth is computed locally).

The service runs the shipped model ``models/frt_unicycle.onnx`` when it exists, else the analytic
test model. The filter's behaviour (beta falls with confidence, stays 1 without) does not depend
on the model and is always checked; the outcome (collision or not) does, and is checked only with
the shipped model.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from experiments import plots
from experiments.run_scenarios import BETA_LOW, RUN_SCENES, bimodal_predictor, run_scenario
from experiments.scenes import scene
from experiments.server import connect

ROOT = Path(__file__).resolve().parent.parent
SHIPPED = ROOT / "models" / "frt_unicycle.onnx"

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


@pytest.fixture(scope="module")
def service(
    tmp_path_factory: pytest.TempPathFactory, analytic_model_path: Path
) -> Iterator[tuple[object, bool]]:
    """An SDK client to a fresh local service, and whether it runs the shipped model."""
    shipped = SHIPPED.is_file() and SHIPPED.with_suffix(".json").is_file()
    model = SHIPPED if shipped else analytic_model_path
    log = tmp_path_factory.mktemp("scenarios") / "service.log"
    with connect(None, model, log) as client:
        yield client, shipped


@pytest.mark.parametrize("name", ["uturn", "stop_sign"])
def test_case_study_outcome(service: tuple[object, bool], name: str) -> None:
    client, shipped = service
    sc = scene(name)
    on = run_scenario(client, sc, True, keep_contours=False)
    off = run_scenario(client, sc, False, keep_contours=False)

    for run in (on, off):
        summary = run.summary()
        assert set(summary) >= {
            "detection_distance_m",
            "deceleration_mps2",
            "stop_time_s",
            "collision",
        }
        assert isinstance(summary["collision"], bool)
        assert run.conservative_answers == 0, "every answer must come from the exact set"
        assert run.epsilon is not None
    # The filter, whatever the model: the wrong prediction costs the predictor its confidence...
    assert min(s.beta for s in on.steps) < 2 * BETA_LOW
    # ...unless the confidence is switched off (beta_low = 1 - 1e-6: beta stays 1).
    assert min(s.beta for s in off.steps) > 0.999

    if not shipped:
        pytest.skip(
            "outcome not asserted: models/frt_unicycle.onnx is not there yet, and the analytic "
            "test model (a disc moving straight along the heading) is not a reachable set of the "
            "unicycle, so collision or not says nothing about the method"
        )
    assert on.detection is not None, "with confidence the ego must detect the conflict"
    assert on.detection.can_stop_before_line, on.summary()
    assert not on.collision, on.summary()
    assert off.detection is None or (
        off.detection.distance_to_stop_line_m < on.detection.distance_to_stop_line_m
    )
    # Deterministic (simulated clock, exact sets only): no tolerance for a missing crash.
    assert off.collision, off.summary()


def test_the_bimodal_uturn_is_caught_by_its_mode_posterior(
    service: tuple[object, bool], tmp_path: Path
) -> None:
    """Straight 0.9, U-turn 0.1, confidence off: while the human waits, its actions leave the
    U-turn mode below the floor; its first U-turn action lifts that mode's posterior over the
    straight one's, and (shipped model) the ego then stops before its line without confidence."""
    client, shipped = service
    sc = scene("uturn")
    run = run_scenario(client, sc, False, predictor=bimodal_predictor(sc), keep_contours=False)
    assert run.conservative_answers == 0
    waiting = [s.mode_posteriors for s in run.steps if 0.0 < s.t < sc.driver.start_s]
    turning = [s.mode_posteriors for s in run.steps if s.t > sc.driver.start_s]
    assert waiting and all(p is not None and p[1] < 1e-2 for p in waiting), waiting
    assert turning and turning[0] is not None and turning[0][1] > 0.5, turning[:2]
    assert min(s.beta for s in run.steps) > 0.999  # the mode, not the confidence, did it
    figure = plots.figure_speeds(
        {"uturn_bimodal": {"on": run, "off": run}},
        {"uturn_bimodal": scene(RUN_SCENES["uturn_bimodal"])},
        tmp_path / "speeds.png",
    )
    assert figure.stat().st_size > 0
    if shipped:
        assert run.detection is not None and run.detection.can_stop_before_line, run.summary()
        assert not run.collision, run.summary()


@pytest.mark.parametrize("name", ["uturn", "stop_sign"])
def test_the_uniform_mixture_rule_is_safe_and_detects_no_later_than_the_papers(
    service: tuple[object, bool], name: str
) -> None:
    """With confidence, the rule that mixes in a uniform over the limits (its sets contain the
    paper's rule's at every beta) stops the ego before its line, detecting no later."""
    client, shipped = service
    sc = scene(name)
    paper = run_scenario(client, sc, True, bounds_rule="paper", keep_contours=False)
    mixture = run_scenario(client, sc, True, bounds_rule="uniform_mixture", keep_contours=False)
    assert mixture.conservative_answers == 0
    common = min(len(mixture.steps), len(paper.steps))  # each run ends once its ego has stopped
    assert [s.beta for s in mixture.steps[:common]] == [s.beta for s in paper.steps[:common]]
    if not shipped:
        pytest.skip("outcome not asserted: the analytic test model is not the unicycle's set")
    assert mixture.detection is not None and mixture.detection.can_stop_before_line
    assert not mixture.collision, mixture.summary()
    assert paper.detection is not None
    assert mixture.detection.time_s <= paper.detection.time_s
