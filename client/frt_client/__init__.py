"""Python SDK of the FRT service: forward reachable tubes of human-driven cars, for planners.

>>> from frt_client import FRTClient
>>> with FRTClient("http://127.0.0.1:8000") as frt:          # doctest: +SKIP
...     frt.observe("car-1", timestamp=0.0, state=(0, 0, 0, 5), prediction=pred)
...     frt.collision_check("car-1", [(0.5, 8.0, 0.0)]).collision

:class:`FRTClient` (blocking) and :class:`AsyncFRTClient` (asyncio) have the same methods; their
``stream()`` opens a WebSocket session with the same operations for 10-20 Hz loops. Errors are
subclasses of :class:`FRTError` (see :mod:`frt_client.errors`). numpy arrays are accepted wherever
lists are, but numpy is not required.
"""

from frt_client.adapters import from_apollo, from_autoware
from frt_client.async_client import AsyncFRTClient
from frt_client.async_stream import AsyncStream
from frt_client.client import FRTClient
from frt_client.errors import (
    AuthError,
    ConflictError,
    DeadlineError,
    FRTError,
    NotFoundError,
    PayloadTooLargeError,
    ServerError,
    UnavailableError,
    ValidationError,
)
from frt_client.inputs import (
    BOUND_COLUMNS,
    AgentConfig,
    Footprint,
    HumanState,
    MixturePrediction,
    ObservedAction,
    Prediction,
    PredictionMode,
    TrajectoryPoint,
)
from frt_client.mixtures import from_mixture, from_trajectories
from frt_client.models import (
    Agent,
    AgentConstraints,
    AgentContours,
    AgentMode,
    Audit,
    Belief,
    CollisionAnswer,
    CollisionCheck,
    ConstraintPiece,
    ConstraintSlice,
    ContourPair,
    ContourSet,
    ContourSlice,
    ControlBounds,
    DeleteResult,
    EffectiveConfig,
    FrameRejection,
    FrameResult,
    FRTResult,
    Health,
    LastMiss,
    ModelCard,
    MultiCollisionCheck,
    ObservationResult,
    Readiness,
    RelaxedAssumption,
    TrajectoryAnswer,
)
from frt_client.retry import NO_RETRY, RetryPolicy
from frt_client.stream import Stream

__version__ = "0.1.0"

__all__ = [
    "BOUND_COLUMNS",
    "NO_RETRY",
    "Agent",
    "AgentConfig",
    "AgentConstraints",
    "AgentContours",
    "AgentMode",
    "AsyncFRTClient",
    "AsyncStream",
    "Audit",
    "AuthError",
    "Belief",
    "CollisionAnswer",
    "CollisionCheck",
    "ConflictError",
    "ConstraintPiece",
    "ConstraintSlice",
    "ContourPair",
    "ContourSet",
    "ContourSlice",
    "ControlBounds",
    "DeadlineError",
    "DeleteResult",
    "EffectiveConfig",
    "FRTClient",
    "FRTError",
    "FRTResult",
    "Footprint",
    "FrameRejection",
    "FrameResult",
    "Health",
    "HumanState",
    "LastMiss",
    "MixturePrediction",
    "ModelCard",
    "MultiCollisionCheck",
    "NotFoundError",
    "ObservationResult",
    "ObservedAction",
    "PayloadTooLargeError",
    "Prediction",
    "PredictionMode",
    "Readiness",
    "RelaxedAssumption",
    "RetryPolicy",
    "ServerError",
    "Stream",
    "TrajectoryAnswer",
    "TrajectoryPoint",
    "UnavailableError",
    "ValidationError",
    "from_apollo",
    "from_autoware",
    "from_mixture",
    "from_trajectories",
]
