"""Progress lines for long loops, shared by the stages and the evaluation."""

from __future__ import annotations

import logging
import time
from typing import Callable

log = logging.getLogger("pipeline")


def progress_logger(label: str, every_s: float = 5.0) -> Callable[[int, int], None]:
    """A progress callback that logs a line at most every few seconds, and at the end: done of total,
    the rate since the callback was made, and the time left at that rate."""
    began, last = time.monotonic(), [0.0]

    def report(done: int, total: int) -> None:
        now = time.monotonic()
        if done == total or now - last[0] >= every_s:
            last[0] = now
            rate = done / max(now - began, 1e-9)
            left = f", about {_duration((total - done) / rate)} left" if done < total and rate > 0 else ""
            log.info("%s: %d/%d (%.0f%%), %.3g a second%s", label, done, total, 100.0 * done / max(total, 1), rate,
                     left)

    return report


def _duration(seconds: float) -> str:
    """`seconds` for a person: 42 s, 3 min 5 s, 2 h 10 min."""
    whole = int(round(seconds))
    if whole < 60:
        return f"{whole} s"
    if whole < 3600:
        return f"{whole // 60} min {whole % 60} s"
    return f"{whole // 3600} h {whole % 3600 // 60} min"
