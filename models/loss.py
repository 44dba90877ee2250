"""Self-supervised losses of the value network (DeepReach-style, set semantics).

* HJB PDE residual (paper, eq. hjb without the min with l: the *set* at exactly time t, which stays
  correct when the control bounds vary in time; the tube is the minimum over time slices):
  ``dV/dt + H(x, t, grad_x V) = 0`` with H the optimal Hamiltonian of ``reach.dynamics``.
* Dynamic-programming upper bounds from rollouts of the true dynamics: V(t, xi(t)) <= l(xi(0)).
  These guard against the failure that matters, an under-approximated set.
* An exact lower bound from the heading: theta' = u1 does not depend on the state, so
  |theta(0)| >= distance from theta(t) to the interval of reachable heading changes.
* Optionally, proven lower bounds from heading and speed corridors (reach/corridors.py) at
  precomputed states around the reachable set: where V must be high, which the DP upper bounds
  (pushing V down at reachable states) and a small PDE weight leave the network free to ignore.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from reach.contract import COL, INITIAL_SET
from reach.dynamics import heading_interval, interpolate_bounds, optimal_hamiltonian, wrap_angle


@dataclass(frozen=True)
class LossWeights:
    pde: float = 0.01
    upper: float = 10.0
    lower: float = 1.0
    upper_margin_m: float = 0.05
    corridor: float = 0.0


def hjb_residual(net: torch.nn.Module, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Return (V, dV/dt + H(x, t, grad V)) at the rows of ``x``."""
    x = x.detach().requires_grad_(True)
    value = net(x)[:, 0]
    (grad,) = torch.autograd.grad(value.sum(), x, create_graph=True)
    t = x[:, COL["t"]]
    hamiltonian = optimal_hamiltonian(
        (grad[:, COL["px"]], grad[:, COL["py"]], grad[:, COL["heading"]], grad[:, COL["speed"]]),
        x[:, COL["heading"]],
        x[:, COL["speed"]],
        interpolate_bounds(x, t),
        torch,
    )
    return value, grad[:, COL["t"]] + hamiltonian


def heading_lower_bound(x: torch.Tensor) -> torch.Tensor:
    """A value V can never be below, from the exact reachable heading interval."""
    lo, hi = heading_interval(x, x[:, COL["t"]])
    half = 0.5 * (hi - lo)
    gap = torch.abs(wrap_angle(x[:, COL["heading"]] - 0.5 * (lo + hi), torch)) - half
    gap = torch.where(half >= math.pi, torch.zeros_like(gap), torch.clamp(gap, min=0.0))
    m = INITIAL_SET
    return (gap - m.heading_margin_rad) * m.heading_weight


def training_losses(
    net: torch.nn.Module,
    pde_points: torch.Tensor,
    rollout_upper_bound: torch.Tensor,
    weights: LossWeights,
    bounded: tuple[torch.Tensor, torch.Tensor] | None = None,
) -> dict[str, torch.Tensor]:
    """Losses on a batch whose first ``len(rollout_upper_bound)`` rows are rollout endpoints;
    ``bounded`` = (states, proven lower bounds on V there) for the corridor hinge."""
    value, residual = hjb_residual(net, pde_points)
    pde = (residual**2).mean()
    lower = torch.relu(heading_lower_bound(pde_points) - value).mean()
    rollout_value = value[: rollout_upper_bound.shape[0]]
    upper = torch.relu(rollout_value - rollout_upper_bound + weights.upper_margin_m).mean()
    total = weights.pde * pde + weights.upper * upper + weights.lower * lower
    corridor = torch.zeros(())
    if bounded is not None and weights.corridor > 0:
        states, lower_bound = bounded
        corridor = torch.relu(lower_bound - net(states)[:, 0]).mean()
        total = total + weights.corridor * corridor
    return {"total": total, "pde": pde, "upper": upper, "lower": lower, "corridor": corridor}
