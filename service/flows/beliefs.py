"""Steps 1 and 2 of the next state (``service.flows.next_state``) of many agents at once: each
agent's belief over (mode, beta) updated by its observed action and carried to its new
prediction, then its mode posterior, each mode's beta and the marginal belief over beta.

The agents are grouped by the shapes of their arrays (the modes of the last prediction and of the
new one) and each group goes through the joint-belief functions of ``service.flows.modes``, which
work agent by agent: an agent observed alone gets bit for bit what it gets among others, and a
single Gaussian gets the paper's filter (``service.flows.confidence``; paper, eq. ``beta`` with
the epsilon-static transition) bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass

import numpy as np

from service.flows.confidence import Belief, normalised_rows
from service.flows.modes import (
    joint_beta_marginals,
    joint_mode_betas,
    joint_mode_probs,
    joint_normalised,
    joint_of_beta_beliefs,
    joint_update,
)
from service.runtime.stores import AgentState


@dataclass(frozen=True)
class BeliefStep:
    """What one agent's filter step needs: its last state (None for a new agent), its
    hypotheses [n] and epsilon, the observed action [2] (None: not scored) and the new
    prediction's normalised mode weights [M]."""

    prior: AgentState | None
    betas: np.ndarray
    epsilon: float
    action: np.ndarray | None
    weights: np.ndarray


@dataclass(frozen=True)
class Joint:
    """One agent's updated belief b(m, beta_i): hypotheses [n], the new prediction's weights
    [M] and normalised log-probabilities [M, n]; with, from step 2, its mode posterior [M], each
    mode's point estimate of beta [M] and the marginal belief over beta."""

    betas: np.ndarray
    weights: np.ndarray
    log_probs: np.ndarray
    posterior: np.ndarray | None = None
    mode_betas: np.ndarray | None = None
    marginal: Belief | None = None

    def to_dict(self) -> dict[str, list[float]]:
        """The stored form of the joint belief (``JointBelief.to_dict``)."""
        return {
            "betas": self.betas.tolist(),
            "weights": self.weights.tolist(),
            "log_probs": self.log_probs.tolist(),
        }


def groups(keys: Sequence[Hashable]) -> dict[Hashable, list[int]]:
    """The indices of ``keys`` by key, each in order."""
    out: dict[Hashable, list[int]] = {}
    for i, key in enumerate(keys):
        out.setdefault(key, []).append(i)
    return out


#: One agent's belief over (mode, beta) on the way: normalised log-probabilities [M, n] and the
#: weights [M] its transition mixes back towards.
_Prior = tuple[np.ndarray, np.ndarray]


def _modes_of(prior: AgentState) -> int:
    return 1 if prior.modes is None else len(prior.modes["first_mean"])


def _priors(priors: list[AgentState]) -> tuple[np.ndarray, np.ndarray]:
    """The last states' beliefs over (mode, beta), normalised [G, Mp, n], and their weights
    [G, Mp] (states with Mp modes each); a single Gaussian's is its beta belief as one mode."""
    if priors[0].modes is not None:
        log_probs = np.array([p.modes["belief"]["log_probs"] for p in priors], dtype=np.float64)  # type: ignore[index]
        weights = np.array([p.modes["belief"]["weights"] for p in priors], dtype=np.float64)  # type: ignore[index]
        return joint_normalised(log_probs), weights
    log_probs = np.array([p.belief["log_probs"] for p in priors], dtype=np.float64)
    return normalised_rows(log_probs)[:, None, :], np.ones((len(priors), 1))


def _first_steps(priors: list[AgentState]) -> tuple[np.ndarray, np.ndarray]:
    """Each mode's first predicted step of the last states: means [G, Mp, 2], covs
    [G, Mp, 2, 2] (states with Mp modes each)."""
    if priors[0].modes is not None:
        means = [p.modes["first_mean"] for p in priors]  # type: ignore[index]
        covs = [p.modes["first_cov"] for p in priors]  # type: ignore[index]
    else:
        means = [p.prediction["mean"][:1] for p in priors]
        covs = [p.prediction["cov"][:1] for p in priors]
    return np.array(means, dtype=np.float64), np.array(covs, dtype=np.float64)


def _updated(steps: Sequence[BeliefStep], members: list[int], joints: list[_Prior | None]) -> None:
    """The last beliefs of the agents ``members`` (states with as many modes each), after the
    filter step of those with an action, into ``joints``."""
    priors: list[AgentState] = [steps[i].prior for i in members]  # type: ignore[misc]
    log_probs, weights = _priors(priors)
    scored = [j for j, i in enumerate(members) if steps[i].action is not None]
    if scored:
        means, covs = _first_steps([priors[j] for j in scored])
        actions = np.array([steps[members[j]].action for j in scored])  # type: ignore[misc]
        epsilons = np.array([steps[members[j]].epsilon for j in scored], dtype=np.float64)
        betas = np.array([steps[members[j]].betas for j in scored])
        log_probs[scored] = joint_update(
            log_probs[scored], weights[scored], epsilons, betas, (actions, means, covs)
        )
    for j, i in enumerate(members):
        joints[i] = (log_probs[j], weights[j])


def _carried(steps: Sequence[BeliefStep], joints: list[_Prior | None]) -> list[np.ndarray]:
    """Each agent's belief carried to its new prediction's weights: the same posterior when it
    has as many modes (mode m is mode m), else the marginal belief over beta times the new
    weights; a new agent's is the prior, uniform over beta, times the new weights."""
    out: list[np.ndarray | None] = [None] * len(steps)
    marginals: dict[int, np.ndarray] = {}  # the agents whose belief restarts from one over beta
    for shape, members in groups([None if j is None else j[0].shape for j in joints]).items():
        if shape is None:
            n = steps[members[0]].betas.size
            uniform = normalised_rows(np.full((len(members), n), -math.log(n)))
            marginals.update(zip(members, uniform, strict=True))
            continue
        moved = [i for i in members if steps[i].weights.size != shape[0]]
        for i in members:
            if steps[i].weights.size == shape[0]:
                out[i] = joints[i][0]  # type: ignore[index]
        if moved:
            stacked = np.array([joints[i][0] for i in moved])  # type: ignore[index]
            marginals.update(zip(moved, joint_beta_marginals(stacked), strict=True))
    restarted = list(marginals)
    for _, members in groups([steps[i].weights.size for i in restarted]).items():
        ids = [restarted[k] for k in members]
        weights = np.array([steps[i].weights for i in ids])
        joint = joint_of_beta_beliefs(np.array([marginals[i] for i in ids]), weights)
        for j, i in enumerate(ids):
            out[i] = joint[j]
    return out  # type: ignore[return-value]


def updated_joints(steps: Sequence[BeliefStep]) -> list[Joint]:
    """Step 1 of every agent (see the module): its updated belief over (mode, beta)."""
    joints: list[_Prior | None] = [None] * len(steps)
    keys = [None if s.prior is None else _modes_of(s.prior) for s in steps]
    for key, members in groups(keys).items():
        if key is not None:
            _updated(steps, members, joints)
    carried = _carried(steps, joints)
    return [
        Joint(s.betas, s.weights, log_probs) for s, log_probs in zip(steps, carried, strict=True)
    ]


def summarised(joints: Sequence[Joint]) -> list[Joint]:
    """Step 2 of every agent: its joint with the mode posterior, each mode's beta and the
    marginal belief over beta."""
    out: list[Joint | None] = [None] * len(joints)
    for _, members in groups([j.log_probs.shape for j in joints]).items():
        log_probs = np.array([joints[i].log_probs for i in members])
        betas = np.array([joints[i].betas for i in members])
        posterior = joint_mode_probs(log_probs)
        mode_betas = joint_mode_betas(betas, log_probs)
        marginal = Belief.rows(betas, joint_beta_marginals(log_probs))
        for j, i in enumerate(members):
            joint = joints[i]
            out[i] = Joint(
                joint.betas,
                joint.weights,
                joint.log_probs,
                posterior[j],
                mode_betas[j],
                marginal[j],
            )
    return out  # type: ignore[return-value]
