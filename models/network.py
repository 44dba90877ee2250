"""The parameter-conditioned value network V(t, x; v_start, bounds), with set semantics.

V(t, x) = min over admissible controls of l(xi(0)) where xi(t) = x: the reachable set at exactly
time t is {V <= 0} (paper, "Overview: HJ reachability"; set form of the HJB PDE, see models/loss.py).

The network takes the 14 physical columns of the contract and does its own normalisation:

* a *nominal* trajectory (mid-bound controls from the nominal initial state) and the spreads of the
  controls give a moving frame and length scales, computed in closed form or by fixed quadrature;
* the input state is expressed in that frame, scaled by the spreads;
* the boundary condition V(0, x) = l(x) is imposed exactly (DeepReach's exact-BC variant):
  ``V = l_nominal(t, x) + (t / T) * S(t) * MLP(features)`` where ``l_nominal`` is l(x) carried along the
  nominal trajectory, equal to l(x) at t = 0.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from reach.contract import COL, HORIZON_S, INITIAL_SET, U1_LIMIT, U2_LIMIT, V_START_MAX, InitialSet
from reach.dynamics import wrap_angle


@dataclass(frozen=True)
class NetworkConfig:
    width: int = 192
    depth: int = 4
    quadrature_points: int = 12

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


def asinh_by_logs(z: torch.Tensor) -> torch.Tensor:
    """asinh(z) = sign(z) log(|z| + sqrt(z^2 + 1)): the same function, from ops every ONNX
    runtime kernel has in float64 (onnxruntime's Asinh is float32 only)."""
    return torch.sign(z) * torch.log(torch.abs(z) + torch.sqrt(z * z + 1.0))


def _column(x: torch.Tensor, name: str) -> torch.Tensor:
    return x[:, COL[name]]


class NominalFrame(nn.Module):
    """Nominal trajectory and control spreads, the moving frame in which the MLP sees the state."""

    def __init__(self, quadrature_points: int, horizon: float, initial_set: InitialSet) -> None:
        super().__init__()
        k = quadrature_points
        self.register_buffer("nodes", (torch.arange(k, dtype=torch.float32) + 0.5) / k)
        self.quadrature_points = k
        self.horizon = horizon
        self.initial_set = initial_set

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        T = self.horizon
        t = _column(x, "t")
        v_start = _column(x, "v_start")

        def mid(a: str, b: str) -> torch.Tensor:
            return 0.5 * (_column(x, a) + _column(x, b))

        def half(a: str, b: str) -> torch.Tensor:
            return 0.5 * (_column(x, b) - _column(x, a))

        u1_mid_s, u1_mid_e = mid("u1_min_start", "u1_max_start"), mid("u1_min_end", "u1_max_end")
        u2_mid_s, u2_mid_e = mid("u2_min_start", "u2_max_start"), mid("u2_min_end", "u2_max_end")
        u1_half_s, u1_half_e = (
            half("u1_min_start", "u1_max_start"),
            half("u1_min_end", "u1_max_end"),
        )
        u2_half_s, u2_half_e = (
            half("u2_min_start", "u2_max_start"),
            half("u2_min_end", "u2_max_end"),
        )

        def integral(start: torch.Tensor, end: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
            """Integral over [0, tau] of the linear interpolation start -> end over [0, T]."""
            return start * tau + (end - start) * tau * tau / (2.0 * T)

        tau = t[:, None] * self.nodes[None, :]
        h = t / self.quadrature_points
        s0 = (slice(None), None)
        theta_q = integral(u1_mid_s[s0], u1_mid_e[s0], tau)
        speed_q = torch.relu(v_start[s0] + integral(u2_mid_s[s0], u2_mid_e[s0], tau))
        heading_spread_q = integral(u1_half_s[s0], u1_half_e[s0], tau)
        speed_spread_q = integral(u2_half_s[s0], u2_half_e[s0], tau)

        m = self.initial_set
        heading_spread_q = m.heading_margin_rad + heading_spread_q
        speed_spread_q = m.speed_margin_mps + speed_spread_q
        along_spread = m.radius_m + h * speed_spread_q.sum(dim=1)
        cross_spread = m.radius_m + h * (
            (speed_q + speed_spread_q) * torch.clamp(heading_spread_q, max=1.0)
        ).sum(dim=1)
        return {
            "x": h * (speed_q * torch.cos(theta_q)).sum(dim=1),
            "y": h * (speed_q * torch.sin(theta_q)).sum(dim=1),
            "heading": integral(u1_mid_s, u1_mid_e, t),
            "speed": torch.relu(v_start + integral(u2_mid_s, u2_mid_e, t)),
            "heading_spread": m.heading_margin_rad + integral(u1_half_s, u1_half_e, t),
            "speed_spread": m.speed_margin_mps + integral(u2_half_s, u2_half_e, t),
            "along_spread": along_spread,
            "cross_spread": cross_spread,
        }


class ValueNetwork(nn.Module):
    """V: [N, 14] physical inputs -> [N, 1] value in metres (set semantics, exact boundary condition)."""

    def __init__(
        self,
        config: NetworkConfig | None = None,
        horizon: float = HORIZON_S,
        initial_set: InitialSet = INITIAL_SET,
    ) -> None:
        super().__init__()
        self.config = config or NetworkConfig()
        self.horizon = horizon
        self.initial_set = initial_set
        self.frame = NominalFrame(self.config.quadrature_points, horizon, initial_set)
        layers: list[nn.Module] = []
        width_in = self.n_features
        for _ in range(self.config.depth):
            layers += [nn.Linear(width_in, self.config.width), nn.SiLU()]
            width_in = self.config.width
        last = nn.Linear(width_in, 1)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)
        self.mlp = nn.Sequential(*layers, last)
        self.asinh = torch.asinh

    n_features = 25

    def features(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Return (features, l carried along the nominal trajectory, output scale S)."""
        m = self.initial_set
        nom = self.frame(x)
        t = _column(x, "t")
        dx = _column(x, "px") - nom["x"]
        dy = _column(x, "py") - nom["y"]
        cos_n, sin_n = torch.cos(nom["heading"]), torch.sin(nom["heading"])
        along = cos_n * dx + sin_n * dy
        cross = -sin_n * dx + cos_n * dy
        d_heading = wrap_angle(_column(x, "heading") - nom["heading"], torch)
        d_speed = _column(x, "speed") - nom["speed"]

        distance = torch.sqrt(along * along + cross * cross + 1e-12)
        l_nominal = torch.maximum(
            distance - m.radius_m,
            torch.maximum(
                (torch.abs(d_speed) - m.speed_margin_mps) * m.speed_weight,
                (torch.abs(d_heading) - m.heading_margin_rad) * m.heading_weight,
            ),
        )
        scale = m.radius_m + nom["along_spread"] + nom["cross_spread"]
        bounds = [
            _column(x, name) / (U1_LIMIT if name.startswith("u1") else U2_LIMIT)
            for name in (
                "u1_min_start",
                "u2_min_start",
                "u1_min_end",
                "u2_min_end",
                "u1_max_start",
                "u2_max_start",
                "u1_max_end",
                "u2_max_end",
            )
        ]
        speed_scale = V_START_MAX + 10.0 * self.horizon
        feats = [
            t / self.horizon,
            self.asinh(along / nom["along_spread"]),
            self.asinh(cross / nom["cross_spread"]),
            along / 50.0,
            cross / 50.0,
            torch.sin(d_heading),
            torch.cos(d_heading),
            self.asinh(torch.sin(d_heading) / nom["heading_spread"]),
            self.asinh(d_speed / nom["speed_spread"]),
            d_speed / speed_scale,
            _column(x, "speed") / speed_scale,
            _column(x, "v_start") / V_START_MAX,
            torch.log(nom["along_spread"]),
            torch.log(nom["cross_spread"]),
            torch.log(nom["heading_spread"]),
            torch.log(nom["speed_spread"]),
            nom["heading"] / math.pi,
            *bounds,
        ]
        return torch.stack(feats, dim=1), l_nominal, scale

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats, l_nominal, scale = self.features(x)
        t = _column(x, "t")
        correction = self.mlp(feats)[:, 0]
        return (l_nominal + (t / self.horizon) * scale * correction)[:, None]
