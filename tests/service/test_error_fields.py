"""The field of a refused request comes from the error's ``.argument``, not its wording.

The worker turns a glraster ArgumentError about a request's values into a 422 naming the
request field that carried the value (:data:`glraster.service.protocol.ARGUMENT_FIELDS`).
These run the worker's handler in-process on the test's context (no server to start).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from glraster.client import encode_scene
from glraster.errors import ArgumentError
from glraster.service import protocol
from glraster.service.config import Limits
from glraster.service.worker import Handler

POS = np.array([[-0.9, -0.9, 0, 1], [0.9, -0.9, 0, 1], [0, 0.9, 0, 1]], np.float32)
TRI = np.array([[0, 1, 2]], np.int32)


@pytest.mark.parametrize("argument, field", [
    ("pos", "pos"), ("tri", "tri"), ("resolution", "resolution"), ("outputs", "outputs"),
    ("method", "method"), ("samples", "samples"), ("interpolation", "interpolation"),
    ("cull_backfaces", "cull_backfaces"),
    ("sample_positions", "samples"),   # the worker passes them for the request's samples
    ("out", "body"),                   # set by the worker, not by the client
    ("fill_rule", "body"),
])
def test_the_field_is_the_argument_mapped_to_the_request(argument, field):
    err = protocol.invalid(ArgumentError(argument, f"{argument} is wrong"))
    assert (err.status, err.field, err.message) == (422, field, f"{argument} is wrong")


def test_the_message_wording_is_not_read():
    """A ValueError without an argument names the body, whatever its first word; an
    ArgumentError's field is its argument even when the message starts otherwise."""
    assert protocol.invalid(ValueError("pos must have shape (V, 4)")).field == "body"
    assert protocol.invalid(ArgumentError("tri", "index 7 is beyond pos")).field == "tri"
    assert not hasattr(protocol, "field_of")


def test_long_messages_are_cut_to_500_characters():
    err = protocol.invalid(ArgumentError("pos", "pos " + "x" * 1000))
    assert err.field == "pos" and len(err.message) == 500


def _refusal(ctx, pos, tri, resolution, **options):
    handler = Handler(ctx, Limits())
    meta = {"content_type": protocol.NPZ, "accept": "json",
            "query": {k: str(v).lower() if isinstance(v, bool) else str(v)
                      for k, v in options.items()}}
    with pytest.raises(protocol.RequestError) as err:
        handler.rasterize(meta, encode_scene(pos, tri, resolution))
    return err.value


@pytest.mark.parametrize("case, pos, tri, options, field, words", [
    ("tri index beyond pos", POS, np.array([[0, 1, 7]], np.int32), {}, "tri",
     "tri index 7 is out of range"),
    ("negative tri index", POS, np.array([[0, -1, 2]], np.int32), {}, "tri",
     "tri must hold indices >= 0"),
    ("NaN in pos", np.array([[0, 0, 0, 1], [np.nan, 0, 0, 1], [0, 1, 0, 1]], np.float32), TRI,
     {}, "pos", "row 1 has NaN or Inf"),
    ("pos of 3 columns", np.zeros((3, 3), np.float32), TRI, {}, "pos",
     "pos must have shape (V, 4)"),
    ("samples not a power of two", POS, TRI, {"samples": 3}, "samples",
     "samples must be a power of two"),
    ("reference with samples not a power of two", POS, TRI, {"samples": 3, "reference": True},
     "samples", "samples must be a power of two"),
])
def test_worker_refusals_name_the_field(ctx, case, pos, tri, options, field, words):
    err = _refusal(ctx, pos, tri, (8, 8), **options)
    assert (err.status, err.field) == (422, field), (case, err.body())
    assert words in err.message, (case, err.message)
    doc = json.loads(json.dumps(err.body()))
    assert doc == {"error": err.message, "field": field, "status": 422}


def test_a_sample_count_the_driver_lacks_names_samples(ctx):
    """"samples=N is not offered by this driver": its first word is no field, so the old
    parsing of the message named the body; the argument names samples."""
    lacking = [s for s in (2, 4, 8, 16, 32, 64) if s not in ctx.sample_counts]
    if not lacking:
        pytest.skip("the driver offers every sample count a request may name")
    err = _refusal(ctx, POS, TRI, (8, 8), samples=lacking[0])
    assert (err.status, err.field) == (422, "samples"), err.body()
    assert err.message.startswith(f"samples={lacking[0]} is not offered"), err.message
