"""Effects of beta_low and gamma (paper, section "Case Studies", "Effects of parameters").

- :func:`beta_traces`: the belief evolution over a whole scene for several beta_low (the paper's
  figure ``fig:uturnBel``): the human is observed every 0.5 s with the stand-in predictor and the
  service's beta recorded. Only observations are sent; no ego is involved.
- :func:`gamma_frts`: the FRT for several gamma with the same prediction and beta (the paper's
  figure ``fig:gammaComp``), from the stateless ``POST /v1/frt``.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from experiments.predictor import STEP_S, GaussianPrediction, Observation, observed_action
from experiments.run_scenarios import COLLISION_RADIUS_M, GAMMA, agent_config, predictor_for
from experiments.scenes import Scene

BETA_LOWS: tuple[float, ...] = (0.01, 0.03, 0.075, 0.15)
GAMMAS: tuple[float, ...] = (0.05, 0.075, 0.1, 0.125)


@dataclass(frozen=True)
class BetaTrace:
    """beta (and the belief in beta_low) after each observation of one scene."""

    scene: str
    beta_low: float
    t: list[float]
    beta: list[float]
    belief_low: list[float]
    prediction: list[str]


def beta_traces(
    client: Any, sc: Scene, beta_lows: Sequence[float] = BETA_LOWS, duration_s: float | None = None
) -> list[BetaTrace]:
    """Observe the whole scene once per beta_low; return beta over time for each."""
    human = sc.human_trajectory()
    predictor = predictor_for(sc)
    duration = sc.duration_s if duration_s is None else duration_s
    n = int(duration / STEP_S + 1e-9)
    out = []
    for beta_low in beta_lows:
        agent_id = f"{sc.name}-beta-{uuid.uuid4().hex[:8]}"
        history: list[Observation] = []
        trace = BetaTrace(sc.name, beta_low, [], [], [], [])
        try:
            for k in range(n + 1):
                t = k * STEP_S
                history.append(Observation(t, *map(float, human.state_at(t))))
                prediction = predictor.predict(history)
                action = observed_action(history[-2], history[-1]) if k else None
                answer = client.observe(
                    agent_id,
                    timestamp=t,
                    state=history[-1].state,
                    prediction=prediction.payload(),
                    observed_action=action,
                    config=agent_config(True, beta_low=beta_low) if k == 0 else None,
                )
                trace.t.append(t)
                trace.beta.append(answer.beta)
                trace.belief_low.append(answer.belief.beta_low)
                trace.prediction.append(prediction.mode)
        finally:
            client.delete_agent(agent_id)
        out.append(trace)
    return out


@dataclass(frozen=True)
class GammaFRT:
    """The tube's K and C (GeoJSON, world frame) for one gamma."""

    gamma: float
    beta: float
    K: dict[str, Any]
    C: dict[str, Any]
    control_bounds: dict[str, float]
    conservative: bool


def gamma_frts(
    client: Any,
    state: tuple[float, float, float, float],
    prediction: GaussianPrediction,
    beta: float,
    gammas: Sequence[float] = GAMMAS,
) -> list[GammaFRT]:
    """The FRT of one state and prediction for each gamma (stateless ``POST /v1/frt``)."""
    out = []
    for gamma in gammas:
        r = client.frt(
            state,
            prediction=prediction.payload(),
            beta=beta,
            gamma=gamma,
            collision_radius=COLLISION_RADIUS_M,
            contours={"include": ["K", "C"], "tube": True},
        )
        out.append(
            GammaFRT(
                gamma=gamma,
                beta=beta,
                K=r.contours.tube.K,
                C=r.contours.tube.C,
                control_bounds=r.control_bounds.model_dump(),
                conservative=r.conservative,
            )
        )
    return out


__all__ = ["BETA_LOWS", "GAMMA", "GAMMAS", "BetaTrace", "GammaFRT", "beta_traces", "gamma_frts"]
