"""When to send a call again, and how long to wait first (exponential backoff with jitter).

Only where it is safe:

- the connection could not be opened (``httpx.ConnectError`` / ``ConnectTimeout``): the request never
  left the client, so any call may be sent again, an observation included;
- the service answered 503 (model still loading, store full) to an idempotent call (reads, checks,
  deletes, the stateless FRT). An observation is never sent twice after it reached the service.

Timeouts are not retried: the caller's time budget is spent, and a planner should decide what to do.
"""

from __future__ import annotations

import logging
import random
from dataclasses import dataclass
from typing import Any

import httpx

log = logging.getLogger("frt_client.retry")

#: Errors raised before any byte of the request was sent.
NOT_SENT_ERRORS: tuple[type[Exception], ...] = (httpx.ConnectError, httpx.ConnectTimeout)


@dataclass(frozen=True)
class RetryPolicy:
    """Exponential backoff: attempt ``k`` (0-based) waits ``backoff_s * multiplier**k``, at most
    ``max_backoff_s``, scaled by a random factor in ``[1 - jitter, 1]``.

    ``retries`` is the number of extra attempts after the first (0 disables retries). A 503 with a
    ``Retry-After`` header waits that long instead, still capped at ``max_backoff_s``.
    """

    retries: int = 3
    backoff_s: float = 0.05
    multiplier: float = 2.0
    max_backoff_s: float = 1.0
    jitter: float = 0.5

    def __post_init__(self) -> None:
        if self.retries < 0 or self.backoff_s < 0 or self.max_backoff_s < 0:
            raise ValueError("retries, backoff_s and max_backoff_s must be >= 0")
        if self.multiplier < 1 or not 0 <= self.jitter <= 1:
            raise ValueError("multiplier must be >= 1 and jitter in [0, 1]")

    def backoff(self, attempt: int, retry_after: float | None = None) -> float:
        """Seconds to wait before attempt ``attempt + 1``."""
        if retry_after is not None:
            return min(max(retry_after, 0.0), self.max_backoff_s)
        delay = min(self.backoff_s * self.multiplier**attempt, self.max_backoff_s)
        return delay * (1.0 - self.jitter * random.random())

    def delay(
        self,
        attempt: int,
        *,
        idempotent: bool,
        response: httpx.Response | None = None,
        error: Exception | None = None,
        ok_statuses: tuple[int, ...] = (),
    ) -> float | None:
        """Seconds to wait before sending again, or ``None`` to give up and report."""
        if attempt >= self.retries:
            return None
        if error is not None:
            return self.backoff(attempt) if isinstance(error, NOT_SENT_ERRORS) else None
        if (
            response is not None
            and response.status_code == 503
            and idempotent
            and 503 not in ok_statuses
        ):
            return self.backoff(attempt, _retry_after(response.headers.get("retry-after")))
        return None


NO_RETRY = RetryPolicy(retries=0)


def note(what: str, attempt: int, delay: float, why: object) -> None:
    """Log one retry (logger ``frt_client.retry``, level INFO)."""
    log.info(
        "retrying %s in %.3f s (attempt %d): %s",
        what,
        delay,
        attempt + 2,
        why,
        extra={"frt_retry_attempt": attempt + 1, "frt_retry_delay_s": delay},
    )


def _retry_after(value: Any) -> float | None:
    """``Retry-After`` in seconds (only the delta-seconds form; a date is ignored)."""
    try:
        return float(value) if value is not None else None
    except ValueError:
        return None
