"""Progress lines for long loops, shared by the stages and the evaluation."""

from __future__ import annotations

import logging
import time
from typing import Callable

log = logging.getLogger("pipeline")


def progress_logger(label: str, every_s: float = 5.0) -> Callable[[int, int], None]:
    """A progress callback that logs a line at most every few seconds, and at the end."""
    last = [0.0]

    def report(done: int, total: int) -> None:
        now = time.monotonic()
        if done == total or now - last[0] >= every_s:
            last[0] = now
            log.info("%s: %d/%d (%.0f%%)", label, done, total, 100.0 * done / max(total, 1))

    return report
