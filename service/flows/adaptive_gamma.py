"""Adaptive gamma: adaptive conformal inference on the audit's misses of C.

Gibbs, I. and Candès, E. (2021), "Adaptive Conformal Inference Under Distribution Shift",
NeurIPS 34 (arXiv:2106.00170), their update ``alpha_{t+1} = alpha_t + eta (alpha - err_t)``, with
``err_t`` = 1 when the set built at level ``alpha_t`` misses the outcome. Here the level is gamma,
the Gaussian mass each control interval holds (API.md, "Observation"): sets grow with gamma, as the
conformal sets grow as alpha falls. With ``a = 1 - target`` (the miss rate to hold) and one step
per audited position (``service.runtime.audit``):

    g <- max(g + eta (err - a), GAMMA_MIN),    err = 1 if the position is outside C,

and the agent's next sets are built with ``gamma = min(g, GAMMA_MAX)`` (a miss raises gamma by
``eta * target``; a hit lowers it by ``eta * (1 - target)``: slowly, for a target near 1). ``g``
starts at the agent's configured gamma.

What it guarantees (Gibbs & Candès's coverage bound, by telescoping the update): over the agent's
first T audited positions, for any sequence of humans and predictions, adversarial included,

    misses / T  <=  a + (g_(T+1) - g_1) / (eta T)

(the floor only raises g, so it keeps the inequality). ``g`` is reported (``audit.gamma_state``).
It stays bounded, and the miss rate's excess over ``a`` vanishes as 1/T, as long as sets built at
``GAMMA_MAX`` do not keep missing: g then exceeds GAMMA_MAX by at most the jumps of the misses
already under way from versions built earlier (at most ``eta`` times the pairs audited over one
horizon). What it does not guarantee: anything at a single step or for a single situation
(conditional coverage): the set may miss with high probability right after a change, in a turn,
for one class of car, as long as the long-run average holds; nothing bounds the size of the sets
(gamma may sit at GAMMA_MAX); and when the human leaves even the GAMMA_MAX set (beyond the hard
control limits, tracking noise beyond the initial set) g grows and the bound says so, but no gamma
restores the target.
"""

from __future__ import annotations

#: The range of the gamma the rule serves (API.md: gamma in (0, 1)).
GAMMA_MIN = 0.01
GAMMA_MAX = 0.999


def next_state(g: float, audited: int, missed: int, target: float, step: float) -> float:
    """The rule's state after ``audited`` positions of which ``missed`` fell outside C."""
    return max(g + step * (missed - (1.0 - target) * audited), GAMMA_MIN)


def served_gamma(g: float) -> float:
    """The gamma the agent's next sets are built with."""
    return min(max(g, GAMMA_MIN), GAMMA_MAX)
