"""glraster.studies.timing: the warm-up calls are not timed, every timed call is one sample,
and the clock is the one given."""

from __future__ import annotations

import itertools

from glraster.studies import timing


def test_warmup_calls_are_untimed_and_each_timed_call_is_one_sample():
    calls = []
    ticks = itertools.count(0.0, 0.5)           # a clock that advances 0.5 s per reading
    samples = timing.seconds_per_call(lambda: calls.append(1), 3, warmup=2,
                                      clock=lambda: next(ticks))
    assert len(calls) == 5                        # 2 warm-up + 3 timed
    assert samples == [0.5, 0.5, 0.5]             # two clock readings per timed call


def test_median_and_best_of_the_samples():
    durations = iter([3.0, 1.0, 2.0])
    now = [0.0]

    def fn():
        now[0] += next(durations)

    assert timing.median_seconds(fn, 3, clock=lambda: now[0]) == 2.0
    durations = iter([3.0, 1.0, 2.0])
    assert timing.best_seconds(fn, 3, clock=lambda: now[0]) == 1.0
