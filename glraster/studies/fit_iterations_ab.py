"""Iterations per second of the glraster.torch fits, a mipmapped texture call on a
texture that does not change, and the environment-map workload, for two source trees in
one run (interleaved A/B).

    glraster study fit-iterations-ab --before-commit ada30fd --rounds 5

``--before`` is a checkout of the older tree (``--before-commit`` makes a temporary git
worktree of that commit instead and removes it afterwards; ada30fd is the tree before the
fits' speed work); ``--after`` is this tree. One interpreter per tree, warmed up once,
each importing glraster from its own tree (checked: a worker names the package it
imported); each round asks them in alternating order for each case in turn (interleaved
A/B, so both see the same load):

- ``cube 4x4``, ``cube 16x16``: the cube fit (``fit_cube``: 4 views, rasterize ->
  interpolate -> antialias, Adam);
- ``pose``: the pose fit (``fit_pose``, 2 restarts) at ``--size`` (256);
- ``texture``: forward + backward of a linear-mipmap-linear ``texture`` call at that size
  on a constant RGBA texture of that size (``mip=None``, gradients to uv and uv_da);
- ``envmap``: the environment-map + Phong iteration written as a user's nvdiffrast code
  would (:func:`envmap_iteration`; only names that both trees' ``glraster.torch`` have):
  the 30,720-triangle blob and the 6 x 512² studio cube map of ``fit envmap``, 2 views at
  ``--envmap-resolution`` (256²), ``rasterize`` with ``grad_db``, ``interpolate`` with
  ``rast_db`` and ``diff_attrs="all"``, two ``texture`` calls on the cube map
  (linear-mipmap-linear with uv_da, ``mip=None``, the diffuse one with a mip bias), a
  target render without autograd and a fit render, one Adam step on the material. The
  scene (mesh, cube map, a pool of views) is built once in this process with this tree's
  :mod:`glraster.fitting.scenes` and handed to both workers as an .npz, since older trees
  lack it.

The table gives the median over rounds, the range, after / before of the medians and the
median of each round's after / before (paired: both trees measured back to back).
float32 on OpenGL, one torch thread (as ``glraster fit``). Timings on a shared machine
are noisy: read the paired ratio and the ranges.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
CASES = ("cube 4x4", "cube 16x16", "pose", "texture", "envmap")
LABELS = {"texture": "texture mip=None, constant tex"}
DEFAULT_BEFORE = "ada30fd"


# --------------------------------------------------------------------------- envmap


def write_envmap_scene(path, *, mesh=(128, 120), env_size: int = 512, views: int = 2,
                       pool: int = 8, seed: int = 0) -> None:
    """The environment-map workload's inputs as an .npz at ``path`` (this tree's
    :mod:`glraster.fitting.scenes` and :mod:`glraster.torch.fitting.envmap`): ``verts``
    (V, 3), ``tri`` (T, 3) int32, ``normals`` (V, 3), ``env`` (1, 6, N, N, 3) float32,
    ``mvp`` (pool, views, 4, 4) and ``eye`` (pool, views, 3) of seeded random views,
    ``sun`` (3,), ``bias`` (the diffuse lookup's mip bias, log2 N - 2) and the true
    and start materials (``kd``, ``ks``, ``p``; ``kd0``, ``ks0``, ``p0``)."""
    import numpy as np

    from glraster.fitting.scenes import SUN_DIRECTION, blob, random_quaternions
    from glraster.fitting.scenes import studio_cube_map
    from glraster.torch.fitting.envmap import TRUE_MATERIAL, view_setup

    verts, faces, normals = blob(*mesh)
    rng = np.random.default_rng(seed)
    setups = [view_setup(random_quaternions(rng, views)) for _ in range(pool)]
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    np.savez(path, verts=f32(verts), tri=np.asarray(faces, np.int32), normals=f32(normals),
             env=f32(studio_cube_map(env_size)[None]),
             mvp=f32([m.numpy() for m, _ in setups]), eye=f32([e.numpy() for _, e in setups]),
             sun=f32(SUN_DIRECTION), bias=np.float32(math.log2(env_size) - 2.0),
             kd=f32(TRUE_MATERIAL["diffuse"]), ks=f32(TRUE_MATERIAL["specular"]),
             p=np.float32(TRUE_MATERIAL["exponent"]),
             kd0=f32(rng.uniform(0.05, 0.95, 3)), ks0=f32(rng.uniform(0.05, 0.6, 3)),
             p0=np.float32(30.0))


def envmap_render(dr, glctx, scene: dict, mvp, eye, kd, ks, p, resolution: int):
    """(N, R, R, 3) Phong images under the cube map and the (N, R, R) coverage: the
    shading of :func:`glraster.torch.fitting.envmap.render_envmap` in nvdiffrast's calls
    (``dr``: the ``glraster.torch`` module of the tree under test), the pyramid built in
    every ``texture`` call (``mip=None``), as a user's nvdiffrast code does."""
    import torch

    verts, tri, n, env = scene["verts"], scene["tri"], scene["normals"], scene["env"]
    homogeneous = torch.cat([verts, torch.ones_like(verts[:, :1])], dim=1)
    clip = torch.einsum("bij,vj->bvi", mvp, homogeneous).contiguous()
    rast, rast_db = dr.rasterize(glctx, clip, tri, (resolution, resolution), grad_db=True)
    view = eye[:, None, :] - verts[None]
    view = view / view.norm(dim=-1, keepdim=True)
    refl = 2.0 * (view * n).sum(-1, keepdim=True) * n - view
    attrs = torch.cat([n.expand_as(refl), refl], dim=-1).contiguous()
    pix, pix_da = dr.interpolate(attrs, rast, tri, rast_db=rast_db, diff_attrs="all",
                                 glctx=glctx)
    n_pix, r_pix = pix[..., :3].contiguous(), pix[..., 3:].contiguous()
    n_da, r_da = pix_da[..., :6].contiguous(), pix_da[..., 6:].contiguous()
    bias = torch.full(n_pix.shape[:-1], float(scene["bias"]))
    lookup = dict(filter_mode="linear-mipmap-linear", boundary_mode="cube", glctx=glctx)
    diffuse = dr.texture(env, n_pix, n_da, bias, **lookup)
    mirror = dr.texture(env, r_pix, r_da, **lookup)
    cos = (r_pix * scene["sun"]).sum(-1, keepdim=True) / r_pix.norm(
        dim=-1, keepdim=True).clamp_min(1e-12)
    lobe = torch.exp(p * torch.log(cos.clamp_min(1e-6)))
    covered = rast[..., 3] > 0
    return (kd * diffuse + ks * (mirror + lobe)) * covered[..., None], covered


def envmap_iteration(dr, glctx, path, resolution: int):
    """run(n): n iterations of the environment-map material fit on the scene at ``path``
    (:func:`write_envmap_scene`), cycling through its views: target render (no autograd),
    fit render, masked MSE, Adam step on (kd, ks, log p), kd and ks clamped to [0, 1]."""
    import numpy as np
    import torch

    with np.load(path) as data:
        scene = {k: torch.from_numpy(np.array(v)) for k, v in data.items()}
    kd = scene["kd0"].clone().requires_grad_(True)
    ks = scene["ks0"].clone().requires_grad_(True)
    log_p = torch.log(scene["p0"]).clone().requires_grad_(True)
    opt = torch.optim.Adam([{"params": [kd, ks]}, {"params": [log_p], "lr": 0.15}], lr=0.06)
    step = [0]

    def run(n: int) -> None:
        for _ in range(n):
            k = step[0] % len(scene["mvp"])
            step[0] += 1
            mvp, eye = scene["mvp"][k], scene["eye"][k]
            with torch.no_grad():
                target, covered = envmap_render(dr, glctx, scene, mvp, eye, scene["kd"],
                                                scene["ks"], scene["p"], resolution)
            image, _ = envmap_render(dr, glctx, scene, mvp, eye, kd, ks, torch.exp(log_p),
                                     resolution)
            m = covered[..., None].to(image.dtype)
            loss = torch.sum(m * (image - target) ** 2) / (torch.sum(m).clamp_min(1.0) * 3)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            with torch.no_grad():
                kd.clamp_(0.0, 1.0)
                ks.clamp_(0.0, 1.0)

    return run


# --------------------------------------------------------------------------- workers


def cases(iterations: int, size: int, names=CASES, envmap=None) -> dict:
    """{case: (run(n), n)} of the cases ``names``: each run does n iterations (or
    calls). envmap: (scene .npz path, resolution) for the "envmap" case."""
    import torch

    import glraster.torch as dr
    from glraster.torch.fitting.cube import fit_cube
    from glraster.torch.fitting.pose import fit_pose

    torch.set_num_threads(1)
    glctx = dr.RasterizeGLContext()
    tex = torch.rand(1, size, size, 4, generator=torch.Generator().manual_seed(0))
    s = (torch.arange(size) + 0.5) / size
    uv = torch.stack(torch.meshgrid(s, s * 0.7, indexing="xy"), -1)[None].contiguous()
    uv_da = torch.tensor([0.9, 0.1, 0.2, 1.7]).expand(1, size, size, 4) / size
    uv.requires_grad_()
    uv_da = uv_da.contiguous().requires_grad_()

    def texture_calls(n):
        for _ in range(n):
            out = dr.texture(tex, uv, uv_da, filter_mode="linear-mipmap-linear", glctx=glctx)
            out.sum().backward()

    few = max(iterations // 5, 4)
    table = {"cube 4x4": (lambda n: fit_cube(glctx, 4, 0, iterations=n), iterations),
             "cube 16x16": (lambda n: fit_cube(glctx, 16, 0, iterations=n), iterations),
             "pose": (lambda n: fit_pose(glctx, 0, resolution=size, restarts=2,
                                         iterations=n, jumps=()), few),
             "texture": (texture_calls, few)}
    if "envmap" in names:
        table["envmap"] = (envmap_iteration(dr, glctx, *envmap), max(iterations // 50, 2))
    return {name: table[name] for name in names}


def serve(iterations: int, size: int, names, envmap) -> None:
    """Read case names from stdin, one a line; answer each with its rate per second."""
    import glraster

    table = cases(iterations, size, names, envmap)
    for name, (run, n) in table.items():
        run(1 if name == "envmap" else max(n // 10, 2))     # warm: shaders, buffers
    print("ready", Path(glraster.__file__).resolve(), flush=True)
    for line in sys.stdin:
        run, n = table[line.strip()]
        start = time.perf_counter()
        run(n)
        print(n / (time.perf_counter() - start), flush=True)


def _start(tree: Path, iterations: int, size: int, names, envmap) -> subprocess.Popen:
    from glraster.studies import revision  # here: the worker runs this file in its tree

    env = revision.tree_environment(tree)
    command = [sys.executable, str(HERE), "--worker", "--iterations", str(iterations),
               "--size", str(size), "--cases", *names]
    if envmap is not None:
        command += ["--envmap-scene", str(envmap[0]), "--envmap-resolution", str(envmap[1])]
    proc = subprocess.Popen(command, cwd=tree, env=env, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    word, _, where = proc.stdout.readline().strip().partition(" ")
    if word != "ready":
        proc.kill()
        raise RuntimeError(f"the worker in {tree} did not start (its error is above)")
    if not Path(where).is_relative_to(tree):
        proc.kill()
        raise RuntimeError(f"the worker for {tree} imported glraster from {where}")
    return proc


def _ask(proc: subprocess.Popen, case: str) -> float:
    proc.stdin.write(case + "\n")
    proc.stdin.flush()
    answer = proc.stdout.readline()
    if not answer:
        raise RuntimeError(f"a worker stopped during {case!r} (its error is above)")
    return float(answer)


def compare(before: Path, after: Path, *, rounds: int = 5, iterations: int = 200,
            size: int = 256, names=CASES, envmap_resolution: int = 256,
            envmap_mesh=(128, 120), envmap_env_size: int = 512, progress=None) -> list:
    """Rows {"case", "label", "before", "after": (median, min, max) /s, "ratio" (after /
    before of the medians), "paired" (median of the rounds' after / before)} of the
    interleaved A/B of the trees ``before`` and ``after`` (checkouts). progress:
    optional callable (round, rounds)."""
    trees = {"before": Path(before).resolve(), "after": Path(after).resolve()}
    runs = {name: [{} for _ in range(rounds)] for name in trees}
    with tempfile.TemporaryDirectory() as tmp:
        envmap = None
        if "envmap" in names:
            envmap = (Path(tmp) / "envmap.npz", envmap_resolution)
            write_envmap_scene(envmap[0], mesh=envmap_mesh, env_size=envmap_env_size)
        workers = {}
        try:
            for name, tree in trees.items():
                workers[name] = _start(tree, iterations, size, names, envmap)
            for r in range(rounds):
                if progress is not None:
                    progress(r + 1, rounds)
                for case in names:
                    for name in (list(trees) if r % 2 == 0 else list(trees)[::-1]):
                        runs[name][r][case] = _ask(workers[name], case)
        finally:
            for proc in workers.values():
                proc.stdin.close()
                proc.wait(timeout=120)
    rows = []
    for case in names:
        cells = {}
        for name in trees:
            values = [run[case] for run in runs[name]]
            cells[name] = (statistics.median(values), min(values), max(values))
        paired = statistics.median(r_after[case] / r_before[case]
                                   for r_before, r_after in zip(runs["before"], runs["after"]))
        label = LABELS.get(case, case)
        if case in ("pose", "texture"):
            label = f"{label} {size}²"
        elif case == "envmap":
            label = f"{label} {envmap_resolution}²"
        rows.append({"case": case, "label": label, **cells,
                     "ratio": cells["after"][0] / cells["before"][0], "paired": paired})
    return rows


def table(rows: list) -> str:
    """The rows of :func:`compare` as a Markdown table."""
    lines = ["| case | before /s | after /s | after / before | median of the rounds' ratios |",
             "|---|---|---|---|---|"]
    for row in rows:
        (b, b0, b1), (a, a0, a1) = row["before"], row["after"]
        digits = 1 if b >= 10 else 2
        lines.append(f"| {row['label']} | {b:.{digits}f} [{b0:.{digits}f} .. {b1:.{digits}f}] "
                     f"| {a:.{digits}f} [{a0:.{digits}f} .. {a1:.{digits}f}] "
                     f"| {row['ratio']:.2f} | {row['paired']:.2f} |")
    return "\n".join(lines)


class BeforeTree:
    """The older tree as a path: ``path`` itself, or a temporary detached git worktree of
    ``commit`` (made from the repository at ``repo``), removed on leaving."""

    def __init__(self, path=None, commit=None, repo=HERE.parents[2]):
        self.path, self.commit, self.repo = path, commit, Path(repo)
        self._tmp = None

    def __enter__(self) -> Path:
        if self.commit is None:
            return Path(self.path).resolve()
        self._tmp = tempfile.TemporaryDirectory()
        where = Path(self._tmp.name) / "before"
        subprocess.run(["git", "-C", str(self.repo), "worktree", "add", "--detach", "--quiet",
                        str(where), self.commit], check=True)
        self.path = where
        return where

    def __exit__(self, *exc) -> None:
        if self._tmp is not None:
            subprocess.run(["git", "-C", str(self.repo), "worktree", "remove", "--force",
                            str(self.path)], check=False)
            self._tmp.cleanup()


def main(argv=None) -> int:
    # a plain parser, not studies.registry's: the workers run this file against older
    # trees, which may not have the registry
    parser = argparse.ArgumentParser(prog="glraster study fit-iterations-ab",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", type=Path, help="a checkout of the older tree")
    parser.add_argument("--before-commit", help="or: a commit to check out as the older "
                        f"tree (a temporary git worktree), e.g. {DEFAULT_BEFORE}")
    parser.add_argument("--after", type=Path, default=HERE.parents[2])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=200,
                        help="cube iterations per round (pose, texture: a fifth; envmap: "
                             "a fiftieth, at least 2)")
    parser.add_argument("--size", type=int, default=256, help="pose and texture image size")
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    parser.add_argument("--envmap-resolution", type=int, default=256)
    parser.add_argument("--envmap-mesh", type=int, nargs=2, default=[128, 120],
                        metavar=("NU", "NV"), help="the blob's grid (2 NU NV triangles)")
    parser.add_argument("--envmap-env-size", type=int, default=512,
                        help="cube-map face size")
    parser.add_argument("--json", help="also write the rows here")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--envmap-scene", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        envmap = (args.envmap_scene, args.envmap_resolution) if args.envmap_scene else None
        serve(args.iterations, args.size, args.cases, envmap)
        return 0
    # here, not as an argparse action: the worker runs this file on another tree's glraster
    from glraster.io.destinations import refuse_unwritable

    refuse_unwritable(parser, "--json", args.json)
    if (args.before is None) == (args.before_commit is None):
        parser.error(f"give one of --before PATH or --before-commit COMMIT (e.g. "
                     f"{DEFAULT_BEFORE})")
    for option in ("rounds", "iterations", "size", "envmap_resolution", "envmap_env_size"):
        if getattr(args, option) < 1:
            parser.error(f"--{option.replace('_', '-')} must be at least 1")
    with BeforeTree(args.before, args.before_commit, args.after) as before:
        rows = compare(before, args.after, rounds=args.rounds, iterations=args.iterations,
                       size=args.size, names=args.cases,
                       envmap_resolution=args.envmap_resolution,
                       envmap_mesh=tuple(args.envmap_mesh),
                       envmap_env_size=args.envmap_env_size)
    print(f"medians of {args.rounds} rounds (one warm interpreter per tree, the two "
          "alternating case by case) [range]; iterations (texture: calls) per second")
    print(table(rows))
    if args.json:
        from glraster.io.atomic import write_text

        write_text(args.json, json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
