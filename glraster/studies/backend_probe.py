"""What the backend probe adds to a process's first ``glraster.Context()``.

Every round starts three fresh Python processes, in a shuffled order, each timing its first
``Context(BACKEND)`` (the import of glraster excluded):

* ``no probe``: the probe switched off (``probe.require`` replaced by a no-op): the cost
  of the context alone, as before the probe existed;
* ``cold``: an empty ``$XDG_CACHE_HOME``: the probe process runs, then the context is made;
* ``warm``: a cache folder that already holds this environment's verdict: read from disk.

and, in this process, the per-call cost of a verdict already in memory (every Context()
after the first). Medians over the rounds; the machine may be shared, so the rounds are
interleaved. Run::

    glraster study backend-probe [--backend egl] [--rounds 7]
"""

from __future__ import annotations

import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from glraster.studies.registry import argument_parser

# the source tree this module is in, first on the timed processes' path
TREE = Path(__file__).resolve().parents[2]

TIMED = """
import sys, time
import glraster as gr
from glraster.gpu.backends import probe
if sys.argv[2] == "off":
    probe.require = lambda name: None
t = time.perf_counter()
ctx = gr.Context(sys.argv[1])
print(time.perf_counter() - t)
ctx.release()
"""


def first_context_seconds(backend: str, mode: str, cache: str) -> float:
    env = {**os.environ, "XDG_CACHE_HOME": cache,
           "PYTHONPATH": os.pathsep.join([str(TREE), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", TIMED, backend, mode], env=env, check=True,
                         capture_output=True, text=True, timeout=300).stdout
    return float(out.split()[-1])


def verdict_in_memory_seconds(backend: str, cache: str, calls: int = 2000) -> float:
    """Seconds per ``probe.verdict`` call once the verdict is in memory (every Context()
    after a process's first), with ``$XDG_CACHE_HOME`` at ``cache`` during the calls."""
    from glraster.gpu.backends import probe

    before = os.environ.get("XDG_CACHE_HOME")
    os.environ["XDG_CACHE_HOME"] = cache
    try:
        probe.verdict(backend)  # in memory from now on
        t = time.perf_counter()
        for _ in range(calls):
            probe.verdict(backend)
        return (time.perf_counter() - t) / calls
    finally:
        if before is None:
            os.environ.pop("XDG_CACHE_HOME", None)
        else:
            os.environ["XDG_CACHE_HOME"] = before


def main(argv=None) -> int:
    parser = argument_parser("backend-probe", __doc__)
    parser.add_argument("--backend", default="egl", choices=("egl", "osmesa"))
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, got {args.rounds}")

    times: dict = {"no probe": [], "cold": [], "warm": []}
    with tempfile.TemporaryDirectory() as warm_cache:
        first_context_seconds(args.backend, "on", warm_cache)  # fills the warm cache
        for _ in range(args.rounds):
            order = list(times)
            random.shuffle(order)
            for mode in order:
                if mode == "cold":
                    with tempfile.TemporaryDirectory() as cold_cache:
                        seconds = first_context_seconds(args.backend, "on", cold_cache)
                else:
                    seconds = first_context_seconds(
                        args.backend, "off" if mode == "no probe" else "on", warm_cache)
                times[mode].append(seconds)

        in_memory = verdict_in_memory_seconds(args.backend, warm_cache)

    median = {mode: statistics.median(values) for mode, values in times.items()}
    print(f"first Context({args.backend!r}), median of {args.rounds} interleaved rounds "
          f"(fresh processes):")
    for mode in times:
        print(f"  {mode:<9} {1e3 * median[mode]:7.1f} ms")
    print(f"probe cost at first Context(), cold cache: "
          f"{1e3 * (median['cold'] - median['no probe']):+.1f} ms")
    print(f"probe cost at first Context(), verdict on disk: "
          f"{1e3 * (median['warm'] - median['no probe']):+.1f} ms")
    print(f"verdict in memory (every later Context()): {1e6 * in_memory:.0f} us per call")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
