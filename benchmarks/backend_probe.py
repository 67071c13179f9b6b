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

    python benchmarks/backend_probe.py [--backend egl] [--rounds 7]
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

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
           "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", TIMED, backend, mode], env=env, check=True,
                         capture_output=True, text=True, timeout=300).stdout
    return float(out.split()[-1])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
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

        os.environ["XDG_CACHE_HOME"] = warm_cache
        sys.path.insert(0, str(REPO))
        from glraster.gpu.backends import probe

        probe.verdict(args.backend)  # in memory from now on
        calls = 2000
        t = time.perf_counter()
        for _ in range(calls):
            probe.verdict(args.backend)
        in_memory = (time.perf_counter() - t) / calls

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
    sys.exit(main())
