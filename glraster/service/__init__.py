"""glraster as an HTTP rendering service (``glraster serve``; docs/service.md).

Optional: needs the ``[service]`` extra (starlette, uvicorn, msgspec). Built on glraster's public
API only (``glraster.Context``, ``glraster.rasterize``, ``glraster.reference.rasterize``,
``glraster.conformance.check``, ``glraster.io.exr``, ``glraster.io.npz``).

- :mod:`~glraster.service.config`   limits and settings (:class:`ServiceConfig`)
- :mod:`~glraster.service.app`      the Starlette app and the uvicorn server (:func:`serve`)
- :mod:`~glraster.service.pool`     worker processes, the bounded queue, deadlines, recovery
- :mod:`~glraster.service.worker`   one GL context per process: parse, render, encode
- :mod:`~glraster.service.wire`     the frames on a worker's socket pair
- :mod:`~glraster.service.cells`    shared-memory cells for large results
- :mod:`~glraster.service.models`   the request models: the schema and the parser both
                                    come from them
- :mod:`~glraster.service.protocol` request parsing and result encoding (no file system)
- :mod:`~glraster.service.metrics`  Prometheus text metrics
- :mod:`~glraster.service.openapi`  the OpenAPI schema, generated from the models
                                    (docs/openapi.json)

The loopback load test (``glraster serve-bench``) is a study: :mod:`glraster.studies.loadtest`.
"""

from glraster.service.config import Limits, ServiceConfig  # noqa: F401

__all__ = ["Limits", "ServiceConfig"]
