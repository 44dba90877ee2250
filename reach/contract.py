"""The contract: one definition of the input layout, horizon, limits and initial set.

Imported by training, export, evaluation and the service alike (see ../shared/API.md, "The model
contract"). Nothing here imports torch.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

#: Columns of the network's single input `x` ([N, 14], physical units), in order.
COLUMNS: tuple[str, ...] = (
    "t",
    "px",
    "py",
    "heading",
    "speed",
    "v_start",
    "u1_min_start",
    "u2_min_start",
    "u1_min_end",
    "u2_min_end",
    "u1_max_start",
    "u2_max_start",
    "u1_max_end",
    "u2_max_end",
)
COL: dict[str, int] = {name: i for i, name in enumerate(COLUMNS)}
N_INPUTS = len(COLUMNS)
STATE_COLUMNS = ("px", "py", "heading", "speed")
#: The nine parameters that condition the FRT: v_start and the eight control-bound columns.
PARAM_COLUMNS: tuple[str, ...] = COLUMNS[5:]
BOUND_COLUMNS: tuple[str, ...] = COLUMNS[6:]

INPUT_NAME = "x"
OUTPUT_NAME = "value"

#: Prediction horizon T (paper, "Case Studies").
HORIZON_S = 3.0
#: Hard control limits (paper, "Case Studies"): |steering rate| <= 2 rad/s, |acceleration| <= 10 m/s^2.
U1_LIMIT = 2.0
U2_LIMIT = 10.0
#: Range of v_start the shipped network is trained on.
V_START_MAX = 20.0

#: The range of each FRT parameter (v_start and the eight bound columns) the geometry is built for.
PARAM_RANGES: dict[str, tuple[float, float]] = {
    "v_start": (0.0, V_START_MAX),
    **{c: (-U1_LIMIT, U1_LIMIT) for c in COLUMNS[6:] if c.startswith("u1_")},
    **{c: (-U2_LIMIT, U2_LIMIT) for c in COLUMNS[6:] if c.startswith("u2_")},
}


@dataclass(frozen=True)
class InitialSet:
    """Margins of the initial set L = {l(x) <= 0} around (0, 0, heading 0, speed v_start).

    The paper's l(x) (Running Example, "Collision Set Update") is a max of three margins; here each
    term is rescaled to metres so the three have the same slope at the boundary:
    ``l = max(|p| - r, (|v - v_start| - e_v) r / e_v, (|wrap(theta)| - e_theta) r / e_theta)``.
    """

    radius_m: float = 0.5
    speed_margin_mps: float = 0.25
    heading_margin_rad: float = 0.05

    @property
    def speed_weight(self) -> float:
        return self.radius_m / self.speed_margin_mps

    @property
    def heading_weight(self) -> float:
        return self.radius_m / self.heading_margin_rad

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


INITIAL_SET = InitialSet()
