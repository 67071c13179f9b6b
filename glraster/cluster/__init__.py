"""glraster on Ray: conformance across a fleet of drivers, and batch rendering of datasets.

The only module that imports ``ray`` (the ``[ray]`` extra). See docs/cluster.md.

- :func:`connect` / :func:`shutdown`: a local cluster by default, or an address;
- :func:`run_check`: the catalog x methods x drivers as Ray tasks (``glraster check --ray``);
- :func:`render_dataset`: scene files or a mesh's views through Ray Data into .npz shards
  and ``manifest.jsonl`` (``glraster batch``).
"""

from glraster.cluster.runtime import connect, driver_name, node_resources, shutdown


def run_check(*args, **kwargs):
    """:func:`glraster.cluster.fleet.run_check`."""
    from glraster.cluster.fleet import run_check as _run

    return _run(*args, **kwargs)


def render_dataset(*args, **kwargs):
    """:func:`glraster.cluster.dataset.render_dataset`."""
    from glraster.cluster.dataset import render_dataset as _render

    return _render(*args, **kwargs)


__all__ = ["connect", "shutdown", "driver_name", "node_resources", "run_check",
           "render_dataset"]
