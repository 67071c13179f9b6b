"""The studies' stopwatch: seconds per call of a function, after optional warm-up calls.

Timings on a machine whose cores are shared drift between blocks: studies interleave what
they compare (A/B rounds) and report medians (or minima, the least disturbed run) of these
samples; they never judge pass or fail on them.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable


def seconds_per_call(fn: Callable[[], object], calls: int, *, warmup: int = 0,
                     clock: Callable[[], float] = time.perf_counter) -> list[float]:
    """``calls`` samples of ``fn()``'s duration in seconds (``clock``: wall time by default;
    ``time.process_time`` counts this process's CPU time, llvmpipe's threads included),
    after ``warmup`` untimed calls (shaders compiled, buffers sized)."""
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(calls):
        start = clock()
        fn()
        samples.append(clock() - start)
    return samples


def median_seconds(fn: Callable[[], object], calls: int, **kwargs) -> float:
    """The median of :func:`seconds_per_call`."""
    return statistics.median(seconds_per_call(fn, calls, **kwargs))


def best_seconds(fn: Callable[[], object], calls: int, **kwargs) -> float:
    """The minimum of :func:`seconds_per_call`: the run least disturbed by other work."""
    return min(seconds_per_call(fn, calls, **kwargs))
