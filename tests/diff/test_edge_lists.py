"""glraster.diff.edge_lists: the antialias work lists equal their NumPy formulation (pairs
by comparing shifted id images, pixels by marking both ends of every pair), in values and
order, on random and structured id images of every degenerate shape."""

import numpy as np
import pytest

from glraster.diff.edge_lists import pair_lists


def _numpy_lists(ids):
    """The formulation: np.nonzero over shifted comparisons, a sort, a mark array."""
    batch, height, width = ids.shape
    b, y, x = np.nonzero(ids[:, :, :-1] != ids[:, :, 1:])
    a_x = (b * height + y) * width + x
    b, y, x = np.nonzero(ids[:, :-1, :] != ids[:, 1:, :])
    a_y = (b * height + y) * width + x
    codes = np.sort(np.concatenate([2 * a_x, 2 * a_y + 1]))
    mark = np.zeros(ids.size, bool)
    for index in (a_x, a_x + 1, a_y, a_y + width):
        mark[index] = True
    return codes.astype(np.uint32), np.flatnonzero(mark).astype(np.uint32)


def _blocks(rng, shape, count):
    """Ids constant on random rectangles (silhouettes), -1 elsewhere."""
    ids = np.full(shape, -1, np.int64)
    batch, height, width = shape
    for t in range(count):
        b = rng.integers(batch)
        y0, x0 = rng.integers(height), rng.integers(width)
        ids[b, y0:y0 + rng.integers(1, height + 1), x0:x0 + rng.integers(1, width + 1)] = t
    return ids


@pytest.mark.parametrize("shape", [(1, 1, 1), (1, 1, 9), (2, 7, 1), (3, 5, 6), (2, 64, 48)])
@pytest.mark.parametrize("kind", ["random", "blocks", "constant"])
def test_lists_equal_the_numpy_formulation(shape, kind):
    rng = np.random.default_rng(sum(shape))
    if kind == "random":
        ids = rng.integers(-1, 3, shape)
    elif kind == "blocks":
        ids = _blocks(rng, shape, 6)
    else:
        ids = np.full(shape, 4)
    codes, pixels = pair_lists(ids)
    want_codes, want_pixels = _numpy_lists(ids)
    assert codes.dtype == pixels.dtype == np.uint32
    assert np.array_equal(codes, want_codes) and np.array_equal(pixels, want_pixels)
    if kind == "constant":
        assert len(codes) == len(pixels) == 0


def test_pairs_do_not_wrap_across_rows_or_images():
    ids = np.zeros((2, 2, 2), np.int64)
    ids[0, 1, 1] = 1              # the last pixel of image 0 ...
    ids[1, 0, 0] = 1              # ... and the first of image 1 share an id: no pair
    codes, pixels = pair_lists(ids)
    assert codes.tolist() == [2 * 1 + 1, 2 * 2] + [2 * 4, 2 * 4 + 1]
    assert pixels.tolist() == [1, 2, 3, 4, 5, 6]


def test_int32_and_sliced_ids():
    ids = np.random.default_rng(1).integers(-1, 2, (4, 9, 11))
    part = ids[1:3]
    codes, pixels = pair_lists(part.astype(np.int32))
    want_codes, want_pixels = _numpy_lists(part)
    assert np.array_equal(codes, want_codes) and np.array_equal(pixels, want_pixels)
    with pytest.raises(ValueError, match="shape"):
        pair_lists(ids[0])


def test_the_encoded_id_channel_gives_the_lists_of_the_decoded_ids():
    """antialias lists rast[..., 3] as it is (a strided float view): the encoding is one to
    one, so the lists are those of the decoded ids, large ids and -0.0 (empty) included."""
    from glraster.diff.ids import MAX_ID, decode_ids, encode_ids

    rng = np.random.default_rng(2)
    tri_id = rng.choice(np.array([-1, 0, 1, 5, (1 << 24) - 1, 1 << 24, MAX_ID - 1]),
                        (3, 17, 13))
    rast = np.zeros(tri_id.shape + (4,), np.float32)
    rast[..., 3] = encode_ids(tri_id)
    rast[..., 3][rast[..., 3] == 0] = rng.choice(np.float32([0.0, -0.0]),
                                                 int((tri_id < 0).sum()))
    got = pair_lists(rast[..., 3])
    want = pair_lists(decode_ids(rast[..., 3]))
    assert all(np.array_equal(a, b) for a, b in zip(got, want))
    assert np.array_equal(got[0], _numpy_lists(tri_id)[0])


def test_rows_taken_and_put_at_the_listed_pixels_of_a_chunk():
    from glraster.diff.edge_lists import put_rows, take_rows

    rng = np.random.default_rng(4)
    values = rng.standard_normal((40, 3)).astype(np.float32)
    pixels = np.sort(rng.choice(30, 7, replace=False)).astype(np.uint32)
    assert np.array_equal(take_rows(values, 10, pixels), values[10 + pixels.astype(int)])
    rows = rng.standard_normal((7, 3)).astype(np.float32)
    want = values.copy()
    want[10 + pixels.astype(int)] = rows
    put_rows(values, 10, pixels, rows)
    assert np.array_equal(values, want)
    put_rows(values, 0, pixels[:0], rows[:0])          # none listed: nothing written
    assert take_rows(values, 0, pixels[:0]).shape == (0, 3)
