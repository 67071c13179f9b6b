"""Sharded outputs of ``glraster batch``: the plan, the shard files and the manifest.

The items of a dataset (:mod:`glraster.cluster.inputs`) are cut, in order, into shards of
``shard_size`` items; shard ``i`` is ``OUT/shard-<i:05d>.npz``, an uncompressed (stored)
.npz (:func:`glraster.io.npz.write_npz`) written atomically, holding for its ``k``-th item
the requested outputs as members ``s<k:04d>.<output>``, arrays exactly as
:func:`glraster.rasterize` returns them:

- ``persp``, ``screen``: (H, W, 3) float32, ``depth``: (H, W) float32, ``tri_id``: (H, W)
  int32 (-1 empty), row 0 at the bottom (GL window coordinates);
- for a multisampled scene file (``samples`` S > 1) the per-sample arrays of
  :class:`glraster.types.Raster` ((H, W, S) and, with interpolation "sample",
  (H, W, S, 3)), plus ``mask`` (H, W, S) bool and ``sample_positions`` (S, 2) float64;

and a member ``manifest``: a 0-d unicode array, the JSON list of the shard's manifest lines.
A shard file therefore says by itself which items it finished: a rerun skips every shard
whose file exists with the planned items (and only those), and ``OUT/manifest.jsonl`` is
rebuilt from the shards at the end of every run, one line per item, each exactly once::

    {"scene": "<item>", "shard": "shard-00003.npz", "keys": {"persp": "s0007.persp", ...}}
    {"scene": "<item>", "shard": "shard-00003.npz", "keys": {}, "error": "ValueError: ..."}

The second form is an item that could not be rendered (a bad file, or one that crashed its
worker twice, :class:`CrashLedger`).
"""

from __future__ import annotations

import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glraster.errors import ArgumentError
from glraster.io.atomic import atomic_write

MANIFEST = "manifest.jsonl"
MANIFEST_MEMBER = "manifest"
LEDGER_DIR = ".attempts"
# An item that was being rendered when its worker died this many times is an error.
CRASHES_BEFORE_ERROR = 2


@dataclass(frozen=True)
class Shard:
    """Shard ``index``: its file name and its items (str) in order."""

    index: int
    items: tuple

    @property
    def file(self) -> str:
        return f"shard-{self.index:05d}.npz"


def plan(items, shard_size: int) -> list:
    """The shards of ``items``: consecutive runs of ``shard_size`` items."""
    if isinstance(shard_size, bool) or not isinstance(shard_size, (int, np.integer)) \
            or shard_size < 1:
        raise ArgumentError(
            "shard_size", f"shard_size must be a positive integer, got {shard_size!r}")
    items = list(items)
    return [Shard(i, tuple(items[j:j + shard_size]))
            for i, j in enumerate(range(0, len(items), shard_size))]


def member(k: int, output: str) -> str:
    return f"s{k:04d}.{output}"


def read_manifest(path) -> list | None:
    """The manifest lines stored in a shard file, or None when there is no readable shard."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return json.loads(str(z[MANIFEST_MEMBER][()]))
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None


def finished(out_dir, shard: Shard) -> list | None:
    """The shard's manifest lines if its file exists and holds exactly its planned items
    (None: render it)."""
    lines = read_manifest(Path(out_dir) / shard.file)
    if lines is None or [ln.get("scene") for ln in lines] != list(shard.items):
        return None
    return lines


def write_shard(out_dir, shard: Shard, results) -> list:
    """Write shard ``shard`` atomically from ``results``: per item, in order, either a dict
    {output: array} or an error message (str). Returns its manifest lines."""
    from glraster.io.npz import write_npz

    arrays, lines = {}, []
    for k, (item, res) in enumerate(zip(shard.items, results)):
        if isinstance(res, str):
            lines.append({"scene": item, "shard": shard.file, "keys": {}, "error": res})
            continue
        keys = {}
        for name, arr in res.items():
            keys[name] = member(k, name)
            arrays[keys[name]] = arr
        lines.append({"scene": item, "shard": shard.file, "keys": keys})
    arrays[MANIFEST_MEMBER] = np.array(json.dumps(lines))
    with atomic_write(Path(out_dir) / shard.file) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(write_npz(arrays))
    return lines


def write_manifest(out_dir, lines) -> Path:
    """``OUT/manifest.jsonl`` (atomically), one JSON line per item."""
    path = Path(out_dir) / MANIFEST
    with atomic_write(path) as tmp:
        with open(tmp, "w", encoding="utf-8") as fh:
            for line in lines:
                fh.write(json.dumps(line) + "\n")
    return path


class CrashLedger:
    """Which item of a shard was being rendered when a worker died, kept beside the outputs
    (``OUT/.attempts/shard-<i>.json``) so that the next attempt, on whichever worker, knows.

    The first attempt of a shard only marks that it started. An attempt that finds the mark
    (an earlier one died) records each item before rendering it; an item that was being
    rendered at :data:`CRASHES_BEFORE_ERROR` deaths is not rendered again but reported as an
    error, so a scene that crashes its worker every time ends the loop instead of the
    retries. The ledger is removed when the shard is written.
    """

    def __init__(self, out_dir, shard: Shard):
        self.path = Path(out_dir) / LEDGER_DIR / f"shard-{shard.index:05d}.json"
        self.state = {"attempts": 0, "at": None, "deaths": {}}
        try:
            self.state = json.loads(self.path.read_text())
        except (OSError, ValueError):
            pass
        self.careful = self.state["attempts"] > 0
        if self.careful and self.state["at"] is not None:  # the last attempt died there
            at = str(self.state["at"])
            self.state["deaths"][at] = self.state["deaths"].get(at, 0) + 1
        self.state["attempts"] += 1
        self.state["at"] = None
        self._save()

    def _save(self):
        with atomic_write(self.path) as tmp:
            Path(tmp).write_text(json.dumps(self.state))

    def crashes(self, k: int) -> int:
        """How many workers died rendering item ``k`` of the shard."""
        return self.state["deaths"].get(str(k), 0)

    def starting(self, k: int) -> None:
        """Item ``k`` is about to be rendered (recorded only after a death)."""
        if self.careful:
            self.state["at"] = k
            self._save()

    def done(self) -> None:
        self.path.unlink(missing_ok=True)
        try:
            os.rmdir(self.path.parent)
        except OSError:
            pass
