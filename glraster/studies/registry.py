"""Every study glraster ships, by name: what ``glraster study --list`` prints and
``glraster study NAME [options]`` runs.

A study is a measurement program (a benchmark, a figure, an A/B timing), never a pass/fail
test. Two kinds:

* a **module study**: a module of :mod:`glraster.studies` with ``main(argv) -> int`` (its
  own argparse options; ``glraster study NAME --help`` lists them). ``python -m
  glraster.studies.MODULE`` runs it too;
* a **command study**: a study that has had its own ``glraster`` subcommand for longer
  (``glraster bench``, ``glraster stress``, ...); ``glraster study NAME`` is that command,
  with the same options.

This module imports nothing but the standard library, so that listing the studies costs
nothing; a study's module is imported when it runs.
"""

from __future__ import annotations

import argparse
import importlib
from dataclasses import dataclass

from glraster.errors import ArgumentError


@dataclass(frozen=True)
class Study:
    """One study. ``module``: the dotted module that holds it; ``summary``: one line;
    ``command``: the ``glraster`` subcommand that runs it (None: ``module.main(argv)``);
    ``extra``: the pyproject extra it needs beyond the core install ("" for none)."""

    name: str
    module: str
    summary: str
    command: str | None = None
    extra: str = ""


_S = "glraster.studies."

STUDIES: dict[str, Study] = {s.name: s for s in (
    # studies with their own glraster subcommand
    Study("bench", _S + "bench", "run time against error of every method, fill limit, "
          "pyrender peer", command="bench"),
    Study("bench-diff", _S + "diff_bench", "differentiable interpolate against plain "
          "PyTorch, and the rasterize backward", command="bench-diff", extra="torch"),
    Study("antialias-study", _S + "antialias", "coverage antialiasing against the exact "
          "area coverage", command="antialias-study"),
    Study("distortion", _S + "distortion", "affine distortion against perspective-correct "
          "mapping (figure)", command="distortion"),
    Study("stress", _S + "stress", "numerical stability sweeps (w range, slivers, far from "
          "the origin)", command="stress"),
    Study("crosscheck", _S + "crosscheck", "glraster against pyrender on the same mesh and "
          "camera", command="crosscheck", extra="mesh"),
    Study("serve-bench", _S + "loadtest", "loopback load test of the HTTP service",
          command="serve-bench", extra="service"),
    # module studies
    Study("core-figures", _S + "core_figures", "coverage and value error against float64 on "
          "random triangles, tolerance calibration (README figures)"),
    Study("area-coverage", _S + "area_coverage", "run time of the exact area coverage"),
    Study("backend-probe", _S + "backend_probe", "what the backend probe adds to the first "
          "Context()"),
    Study("multisample-cost", _S + "multisample_cost", "multisampling cost against another "
          "source tree's rasterize"),
    Study("diff-rasterize-figures", _S + "diff_rasterize_figures", "differentiable "
          "rasterize: accuracy on the catalog, rast_db cost, batches"),
    Study("diff-antialias-figures", _S + "diff_antialias_figures", "differentiable "
          "antialias on the GPU against its float64 reference"),
    Study("texture-baseline", _S + "torch_texture_baseline", "glraster.torch.texture against "
          "the same filters in plain PyTorch (grid_sample)", extra="torch"),
    Study("texture-mip-reuse", _S + "texture_mip_reuse", "texture with the mip pyramid built "
          "in the call against texture_construct_mip", extra="torch"),
    Study("interpolate-adapter", _S + "interpolate_adapter", "glraster.interpolate (the "
          "adapter over the differentiable interpolate) against a plain weighted sum"),
    Study("jax-overhead", _S + "jax_overhead", "per-call cost of glraster.jax (eager and "
          "jit) against glraster.torch and the bare cores", extra="jax"),
    Study("diff-floors", _S + "diff_floors", "each differentiable op against its bare GL "
          "work (floor), and where each fit iteration's time goes", extra="torch"),
    Study("torch-overhead", _S + "torch_overhead", "per-call overhead of the glraster.torch "
          "wrappers over the op cores, against an older tree", extra="torch"),
    Study("deterministic-ab", _S + "deterministic_ab", "the deterministic backward of "
          "rasterize and interpolate against another checkout"),
    Study("fit-iterations-ab", _S + "fit_iterations_ab", "fit iterations per second against "
          "an older tree (warm interpreters, case by case)", extra="torch"),
    Study("speed-goals", _S + "speed_goals", "the differentiable pipeline's speed goals "
          "(fit floors, A/B, bench-diff, texture) with met or missed, in one run",
          extra="torch"),
    Study("metrics-ab", _S + "metrics_ab", "the service's /metrics cost against an earlier "
          "revision's (git)", extra="service"),
    Study("service-cpu-overhead", _S + "service_cpu_overhead", "CPU the service spends per "
          "request beyond the in-process call", extra="service"),
    Study("service-parse-ab", _S + "service_parse_ab", "the worker's request parsing against "
          "an earlier revision's (git)", extra="service"),
)}


def get(name: str) -> Study:
    """The study called ``name``; an :class:`~glraster.errors.ArgumentError` naming the
    choices when there is none."""
    try:
        return STUDIES[name]
    except KeyError:
        raise ArgumentError("NAME", f"NAME {name!r} is not a study; choose from "
                            f"{', '.join(sorted(STUDIES))} (glraster study --list)") from None


def run(name: str, argv: list[str] | None = None) -> int:
    """Run the module study ``name`` with options ``argv``; its exit code. (A command study
    runs through the ``glraster`` CLI, which owns its options.)"""
    study = get(name)
    if study.command is not None:
        raise ArgumentError("NAME", f"NAME {name!r} is the command 'glraster "
                            f"{study.command}'; run it through the glraster CLI")
    return int(importlib.import_module(study.module).main(argv) or 0)


def argument_parser(name: str, doc: str) -> argparse.ArgumentParser:
    """The options parser of module study ``name``: ``prog`` "glraster study NAME" and the
    module docstring ``doc`` (first paragraph as the description, the rest as the epilog)."""
    first, _, rest = doc.strip().partition("\n\n")
    return argparse.ArgumentParser(prog=f"glraster study {name}", description=first,
                                   epilog=rest or None,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
