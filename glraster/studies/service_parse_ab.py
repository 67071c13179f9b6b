"""The service's request parser now against an earlier revision's, in process.

    glraster study service-parse-ab [REV]     # REV default b5fd647, the hand-written parser

Loads ``glraster/service/protocol.py`` of git revision REV beside the current one and times
``parse_rasterize`` on the load test's scenes (glraster.studies.loadtest.make_scene: the
256x256 torus and the 1024x1024 grid) as a JSON body with options, and as an .npz body with
the options in the query. Rounds alternate between the two parsers (the machine's speed
drifts); printed are the medians of the rounds and the median of the per-round differences.
Both parsers must give the same arrays and options.
"""

from __future__ import annotations

import json
import statistics
import time

import numpy as np

from glraster.client import encode_scene
from glraster.service import protocol as current
from glraster.service.config import Limits
from glraster.studies.loadtest import make_scene
from glraster.studies.registry import argument_parser
from glraster.studies.revision import load_module_at


def main(argv=None) -> int:
    parser = argument_parser("service-parse-ab", __doc__)
    parser.add_argument("rev", nargs="?", default="b5fd647", metavar="REV",
                        help="the git revision to compare with (default b5fd647)")
    rev = parser.parse_args(argv).rev
    then = load_module_at(rev, "glraster/service/protocol.py", "protocol_then")
    limits = Limits()
    for name in ("256", "1024"):
        pos, tri, res = make_scene(name)
        body = json.dumps({"pos": pos.tolist(), "tri": tri.tolist(), "resolution": list(res),
                           "outputs": ["persp", "depth"], "compare": False}).encode()
        npz, query = encode_scene(pos, tri, res), {"outputs": "persp,depth", "compare": "false"}
        a = then.parse_rasterize(then.JSON, body, {}, limits)
        b = current.parse_rasterize(current.JSON, body, {}, limits)
        assert np.array_equal(a.pos.astype(np.float32), b.pos.astype(np.float32))
        assert np.array_equal(a.tri, b.tri) and (a.outputs, a.resolution) == (b.outputs,
                                                                             b.resolution)
        calls = {
            "json then": lambda: then.parse_rasterize(then.JSON, body, {}, limits),
            "json now": lambda: current.parse_rasterize(current.JSON, body, {}, limits),
            "npz then": lambda: then.parse_rasterize(then.NPZ, npz, query, limits),
            "npz now": lambda: current.parse_rasterize(current.NPZ, npz, query, limits),
        }
        n = 20 if name == "256" else 4
        times = {k: [] for k in calls}
        for _ in range(11):
            for key, call in calls.items():
                t = time.perf_counter()
                for _ in range(n):
                    call()
                times[key].append((time.perf_counter() - t) / n * 1e3)
        med = {k: statistics.median(v) for k, v in times.items()}
        diff = {kind: statistics.median(b - a for a, b in zip(times[f"{kind} then"],
                                                              times[f"{kind} now"]))
                for kind in ("json", "npz")}
        print(f"{name}: {len(pos)} vertices, {len(tri)} triangles; JSON body "
              f"{len(body) / 1e3:.0f} kB: {rev} {med['json then']:.2f} ms, now "
              f"{med['json now']:.2f} ms (per-round difference {diff['json']:+.2f} ms); .npz "
              f"body + query: {rev} {med['npz then'] * 1e3:.0f} us, now "
              f"{med['npz now'] * 1e3:.0f} us ({diff['npz'] * 1e3:+.0f} us)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
