"""glraster.io.npz: the .npz codec agrees with numpy and zipfile bit for bit, is zero-copy
and aligned, lets the caller veto members before their data is touched, and turns every
malformed archive into NpzError (naming the member at fault)."""

from __future__ import annotations

import io
import struct
import warnings
import zipfile
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from glraster.io.npz import NpzError, npz_nbytes, read_npz, write_npz, write_npz_into

# ---------------------------------------------------------------------------------------
# helpers: archives made by numpy, by zipfile, and by hand


def savez(arrays, compressed=False) -> bytes:
    f = io.BytesIO()
    (np.savez_compressed if compressed else np.savez)(f, **arrays)
    return f.getvalue()


def np_load(data: bytes) -> dict:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return {k: z[k] for k in z.files}


def npy(header: str, payload: bytes, version=(1, 0)) -> bytes:
    """A .npy file with this header dict text (padded like numpy) and this data."""
    text = header.encode("utf-8" if version == (3, 0) else "latin1")
    prefix = 10 if version == (1, 0) else 12
    text += b" " * (-(prefix + len(text) + 1) % 64) + b"\n"
    fmt = "<H" if version == (1, 0) else "<I"
    return b"\x93NUMPY" + bytes(version) + struct.pack(fmt, len(text)) + text + payload


def f4_npy(values, shape=None, header=None) -> bytes:
    a = np.asarray(values, "<f4")
    shape = a.shape if shape is None else shape
    header = header or f"{{'descr': '<f4', 'fortran_order': False, 'shape': {shape!r}, }}"
    return npy(header, a.tobytes())


def zip_of(members, compression=zipfile.ZIP_STORED, comment=b"") -> bytes:
    """members: (filename, bytes) pairs, written by zipfile (duplicates allowed)."""
    f = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)      # "Duplicate name: ..."
        with zipfile.ZipFile(f, "w", compression) as z:
            for name, payload in members:
                z.writestr(name, payload)
            z.comment = comment
    return f.getvalue()


def central_entries(data: bytes) -> list[int]:
    """Offsets of the central directory entries (plain EOCD, no comment)."""
    count, _, cd_off = struct.unpack_from("<HLL", data, len(data) - 22 + 10)
    offsets, p = [], cd_off
    for _ in range(count):
        offsets.append(p)
        nlen, elen, clen = struct.unpack_from("<3H", data, p + 28)
        p += 46 + nlen + elen + clen
    return offsets


def zip64_archive(members) -> bytes:
    """Stored members with every size and offset in ZIP64 extra fields (0xFFFFFFFF in the
    headers) and a ZIP64 end-of-central-directory record: what a > 4 GiB archive looks like."""
    out, cd = bytearray(), bytearray()
    for name, payload in members:
        nb, crc, off = name.encode(), zlib.crc32(payload), len(out)
        extra = struct.pack("<HHQQ", 1, 16, len(payload), len(payload))
        out += struct.pack("<4s5H3L2H", b"PK\x03\x04", 45, 0, 0, 0, 33, crc, 0xFFFFFFFF,
                           0xFFFFFFFF, len(nb), len(extra)) + nb + extra + payload
        extra = struct.pack("<HHQQQ", 1, 24, len(payload), len(payload), off)
        cd += struct.pack("<4s6H3L5H2L", b"PK\x01\x02", 45, 45, 0, 0, 0, 33, crc, 0xFFFFFFFF,
                          0xFFFFFFFF, len(nb), len(extra), 0, 0, 0, 0, 0xFFFFFFFF) + nb + extra
    cd_off, n = len(out), len(members)
    out += cd
    rec64 = len(out)
    out += struct.pack("<4sQ2H2L4Q", b"PK\x06\x06", 44, 45, 45, 0, 0, n, n, len(cd), cd_off)
    out += struct.pack("<4sLQL", b"PK\x06\x07", 0, rec64, 1)
    out += struct.pack("<4s4H2LH", b"PK\x05\x06", 0, 0, 0xFFFF, 0xFFFF, 0xFFFFFFFF,
                       0xFFFFFFFF, 0)
    return bytes(out)


def assert_same(a: np.ndarray, b: np.ndarray):
    """Bit-identical: dtype (byte order included), shape, memory order and every byte."""
    assert a.dtype == b.dtype and a.dtype.str == b.dtype.str, (a.dtype, b.dtype)
    assert a.shape == b.shape, (a.shape, b.shape)
    assert a.tobytes() == b.tobytes()
    if a.ndim > 1 and a.size > 1:
        assert a.flags.f_contiguous == b.flags.f_contiguous


def service_request():
    rng = np.random.default_rng(5)
    return {"pos": rng.standard_normal((2000, 4)).astype(np.float32),
            "tri": rng.integers(0, 2000, (4096, 3)).astype(np.int32),
            "resolution": np.array([640, 480], np.int64)}


RNG = np.random.default_rng(7)
_big = RNG.random((1024, 1024, 3), dtype=np.float32)
ROUND_TRIP = {
    "float32": RNG.standard_normal(17).astype(np.float32),
    "float64": RNG.standard_normal((3, 5)),
    "int32": RNG.integers(-2**31, 2**31, (4, 4), dtype=np.int32),
    "int64": RNG.integers(-2**63, 2**63 - 1, 9, dtype=np.int64),
    "uint8": RNG.integers(0, 256, (2, 3, 4), dtype=np.uint8),
    "bool": RNG.random((7, 3)) > 0.5,
    "complex64": (RNG.standard_normal(6) + 1j * RNG.standard_normal(6)).astype(np.complex64),
    "big_endian_f4": RNG.standard_normal((5, 2)).astype(">f4"),
    "nan_inf": np.array([np.nan, -np.inf, np.inf, -0.0], np.float32),
    "empty": np.zeros((0,), np.float32),
    "empty_rows": np.zeros((0, 4), np.int32),
    "zero_d": np.array(3.5),
    "five": np.arange(5, dtype=np.int16),
    "image": _big,
    "fortran": np.asfortranarray(RNG.standard_normal((6, 7)).astype(np.float32)),
    "strided": _big[::2, 1::3],
    "transposed_3d": RNG.random((3, 4, 5)).transpose(1, 0, 2),
    "json": np.array('{"a": 1, "é": [2]}', dtype="<U20"),
    "json_exact": np.array("json text"),
    "bytes_s": np.array([b"ab", b"cde"], dtype="S3"),
}


# ---------------------------------------------------------------------------------------
# round trips


@pytest.mark.parametrize("key", sorted(ROUND_TRIP))
def test_round_trip_through_read_npz_np_load_and_zipfile(key):
    a = ROUND_TRIP[key]
    data = write_npz({key: a})
    assert len(data) == npz_nbytes({key: a})
    assert zipfile.ZipFile(io.BytesIO(data)).testzip() is None
    for got in (read_npz(data)[key], read_npz(bytearray(data))[key],
                read_npz(memoryview(data))[key], np_load(data)[key]):
        assert got.dtype == a.dtype and got.shape == a.shape
        assert got.tobytes() == a.tobytes()                    # bit identity, NaN included
    if a.flags.f_contiguous and not a.flags.c_contiguous:
        assert read_npz(data)[key].flags.f_contiguous           # stays Fortran-ordered


def test_many_members_keep_their_order_and_match_np_load():
    data = write_npz(ROUND_TRIP)
    got, ref = read_npz(data), np_load(data)
    assert list(got) == list(ROUND_TRIP) == list(ref)
    for k, a in ROUND_TRIP.items():
        assert_same(got[k], ref[k])
        assert got[k].tobytes() == a.tobytes()


def test_non_ascii_names_round_trip():
    arrays = {"déjà": np.arange(3), "x y": np.ones(2)}
    data = write_npz(arrays)
    assert list(read_npz(data)) == list(np_load(data)) == ["déjà", "x y"]
    assert zipfile.ZipFile(io.BytesIO(data)).namelist() == ["déjà.npy", "x y.npy"]


def test_write_npz_into_larger_buffer_returns_npz_nbytes_and_leaves_the_rest():
    arrays = service_request()
    n = npz_nbytes(arrays)
    buf = np.full(n + 1000, 0xAB, np.uint8)
    assert write_npz_into(arrays, buf) == n
    assert (buf[n:] == 0xAB).all()
    assert buf[:n].tobytes() == write_npz(arrays)
    for target in (bytearray(n), memoryview(bytearray(n + 5))):
        assert write_npz_into(arrays, target) == n
        assert bytes(target[:n]) == write_npz(arrays)
    ref = np_load(buf[:n].tobytes())
    for k, a in arrays.items():
        assert_same(ref[k], a)


def test_write_npz_into_a_reused_dirty_buffer_gives_the_same_archive():
    arrays = service_request()
    n = npz_nbytes(arrays)
    buf = bytearray(np.random.default_rng(0).integers(0, 256, n, dtype=np.uint8).tobytes())
    write_npz_into(arrays, buf)
    assert bytes(buf) == write_npz(arrays)


# ---------------------------------------------------------------------------------------
# archives written by others


@pytest.mark.parametrize("compressed", [False, True], ids=["savez", "savez_compressed"])
def test_reads_numpy_savez_bit_identically(compressed):
    data = savez(ROUND_TRIP, compressed)
    got, ref = read_npz(data), np_load(data)
    assert list(got) == list(ref)
    for k in ref:
        assert_same(got[k], ref[k])


@pytest.mark.parametrize("compression", [zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED])
def test_reads_zipfile_archives_with_a_comment(compression):
    a, b = np.arange(12, dtype="<i4").reshape(3, 4), np.array(["x", "yz"])
    members = [("a.npy", npy_bytes(a)), ("b.npy", npy_bytes(b))]
    comment = b"PK\x05\x06 looks like an end record but is a comment" * 3
    got = read_npz(zip_of(members, compression, comment))
    assert_same(got["a"], a)
    assert_same(got["b"], b)


def npy_bytes(a) -> bytes:
    f = io.BytesIO()
    np.save(f, a, allow_pickle=False)
    return f.getvalue()


def test_reads_zip64_extra_fields_and_zip64_end_record():
    a, b = np.arange(10, dtype=np.float64), np.eye(3, dtype=np.uint8)
    data = zip64_archive([("a.npy", npy_bytes(a)), ("b.npy", npy_bytes(b))])
    assert zipfile.ZipFile(io.BytesIO(data)).testzip() is None    # a valid archive
    got = read_npz(data)
    assert_same(got["a"], a)
    assert_same(got["b"], b)


def test_reads_npy_versions_2_and_3_and_non_canonical_headers():
    payload = np.arange(4, dtype="<f4").tobytes()
    canonical = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 2), }"
    reordered = "{'shape': (2, 2), 'fortran_order': False, 'descr': '<f4'}"
    members = [("v2.npy", npy(canonical, payload, (2, 0))),
               ("v3.npy", npy(canonical, payload, (3, 0))),
               ("literal.npy", npy(reordered, payload)),
               ("fortran.npy", npy(canonical.replace("False", "True"), payload))]
    got = read_npz(zip_of(members))
    ref = np.arange(4, dtype="<f4").reshape(2, 2)
    for k in ("v2", "v3", "literal"):
        assert_same(got[k], ref)
    assert got["fortran"].flags.f_contiguous and np.array_equal(got["fortran"], ref.T)


def test_empty_archive_is_an_empty_dict():
    assert read_npz(savez({})) == {}
    assert read_npz(write_npz({})) == {}


# ---------------------------------------------------------------------------------------
# zero copy and alignment


def test_stored_members_are_zero_copy_and_writeable_only_from_writeable_buffers():
    data = bytearray(write_npz(service_request()))
    for a in read_npz(bytes(data)).values():
        assert not a.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            a.reshape(-1)[0] = 0
    got = read_npz(data)
    for a in got.values():
        assert np.shares_memory(a, np.frombuffer(data, np.uint8))
        assert a.flags.writeable
    got["pos"][0, 0] = 123.0                    # writes through to the caller's buffer
    offset = got["pos"].ctypes.data - np.frombuffer(data, np.uint8).ctypes.data
    assert data[offset:offset + 4] == np.float32(123.0).tobytes()


def test_written_member_data_is_64_byte_aligned():
    arrays = {"odd_name_length_x": np.arange(3, dtype=np.int8), **service_request(),
              "json": np.array('{"k": 1}'), "e": np.zeros((0, 3)), "mask": np.ones(5, bool)}
    n = npz_nbytes(arrays)
    raw = np.empty(n + 64, np.uint8)
    start = -raw.ctypes.data % 64
    buf = raw[start:start + n]
    assert buf.ctypes.data % 64 == 0
    write_npz_into(arrays, buf)
    got = read_npz(memoryview(buf))
    for k, a in got.items():
        assert a.ctypes.data % 64 == 0, k
        assert np.shares_memory(a, buf) or a.size == 0
        assert_same(a, arrays[k])
    # and the offsets themselves, independent of where the buffer lives
    z = zipfile.ZipFile(io.BytesIO(buf.tobytes()))
    for info in z.infolist():
        nlen, elen = struct.unpack_from("<HH", buf, info.header_offset + 26)
        npy_start = info.header_offset + 30 + nlen + elen
        hlen = struct.unpack_from("<H", buf, npy_start + 8)[0]
        assert (npy_start + 10 + hlen) % 64 == 0, info.filename


# ---------------------------------------------------------------------------------------
# the check callback


class TooBig(Exception):
    pass


def test_check_sees_every_member_in_order_before_reading():
    seen = []
    data = write_npz(service_request())
    read_npz(data, check=lambda *args: seen.append(args))
    assert seen == [("pos", np.dtype("<f4"), (2000, 4)), ("tri", np.dtype("<i4"), (4096, 3)),
                    ("resolution", np.dtype("<i8"), (2,))]
    assert all(type(s) is int for _, _, shape in seen for s in shape)


def test_check_vetoes_a_zip_bomb_before_anything_is_decompressed():
    bomb = bytearray(savez({"zeros": np.zeros(25_000_000, np.float32)}, compressed=True))
    assert len(bomb) < 1_000_000                      # 100 MB of zeros in ~100 KB

    def limit(name, dtype, shape):
        if np.prod(shape) * dtype.itemsize > 10_000_000:
            raise TooBig(f"{name} is {shape}")

    with pytest.raises(TooBig, match=r"zeros is \(25000000,\)"):
        read_npz(bomb, check=limit)
    # proof that nothing past the header was inflated: cut the deflate stream in half (the
    # directory's compressed size); the check still raises first, while an unchecked read
    # inflates what is there and finds the stream truncated
    entry = central_entries(bytes(bomb))[0]
    csize = struct.unpack_from("<L", bomb, entry + 20)[0]
    struct.pack_into("<L", bomb, entry + 20, csize // 2)
    with pytest.raises(TooBig):
        read_npz(bomb, check=limit)
    with pytest.raises(NpzError, match="truncated") as e:
        read_npz(bomb)
    assert e.value.member == "zeros"


def test_check_runs_for_all_members_before_any_data_and_its_exception_is_unchanged():
    data = bytearray(write_npz({"a": np.arange(100.0), "b": np.arange(3)}))
    data[200] ^= 0xFF                                     # corrupt a's data (a CRC error)

    def refuse_b(name, dtype, shape):
        if name == "b":
            raise ValueError("b is not wanted")

    with pytest.raises(ValueError, match="b is not wanted") as e:
        read_npz(data, check=refuse_b)
    assert type(e.value) is ValueError                     # not wrapped into NpzError
    with pytest.raises(NpzError, match="CRC") as e:
        read_npz(data)
    assert e.value.member == "a"


# ---------------------------------------------------------------------------------------
# malformed archives


def one_member(payload: bytes, name="a.npy", compression=zipfile.ZIP_STORED) -> bytes:
    return zip_of([(name, payload)], compression)


GOOD = f4_npy([1.0, 2.0])


def flipped_crc_byte() -> bytes:
    payload = np.arange(16, dtype="<f4").tobytes()
    data = bytearray(one_member(npy(canon(shape="(16,)"), payload)))
    data[data.find(payload) + 3] ^= 0x01           # a data byte: only the CRC can tell
    return bytes(data)


def corrupt_deflate_stream() -> bytes:
    data = bytearray(one_member(GOOD, compression=zipfile.ZIP_DEFLATED))
    data[35:41] = b"\xff" * 6                      # reserved block type 3 right at the start
    return bytes(data)


def encrypted() -> bytes:
    data = bytearray(one_member(GOOD))
    data[6] |= 1                                   # local header flags
    data[central_entries(bytes(data))[0] + 8] |= 1       # central directory flags
    return bytes(data)


def deflated_size_lie(claimed_values: int, actual_values: int) -> bytes:
    """A deflated member whose header and zip sizes claim `claimed_values` float32s while
    its stream inflates to `actual_values` of them."""
    header = f"{{'descr': '<f4', 'fortran_order': False, 'shape': ({claimed_values},), }}"
    payload = npy(header, np.arange(actual_values, dtype="<f4").tobytes())
    data = bytearray(one_member(payload, compression=zipfile.ZIP_DEFLATED))
    claimed = len(payload) + 4 * (claimed_values - actual_values)
    struct.pack_into("<L", data, central_entries(bytes(data))[0] + 24, claimed)
    struct.pack_into("<L", data, 22, claimed)
    return bytes(data)


def header(text: str) -> bytes:
    """A member with this header dict text and 8 data bytes (two float32)."""
    return one_member(npy(text, bytes(8)))


def canon(descr="'<f4'", fortran="False", shape="(2,)") -> str:
    return f"{{'descr': {descr}, 'fortran_order': {fortran}, 'shape': {shape}, }}"


BAD = {
    # name: (archive, member at fault, word in the message)
    "empty": (b"", None, "too short"),
    "random": (np.random.default_rng(3).bytes(5000), None, "not a zip"),
    "truncated": (write_npz(service_request())[:40000], None, "end-of-central-directory"),
    "trailing_garbage": (write_npz({"a": np.ones(3)}) + b"x", None, "end-of-central-directory"),
    "crc": (flipped_crc_byte(), "a", "CRC"),
    "slash": (one_member(GOOD, "a/b.npy"), "a/b", "'/'"),
    "backslash": (one_member(GOOD, "a\\b.npy"), "a\\b", "'/'"),
    "not_npy": (one_member(GOOD, "notes.txt"), "notes.txt", ".npy"),
    "empty_name": (one_member(GOOD, ".npy"), "", "empty"),
    "duplicate": (zip_of([("a.npy", GOOD), ("a.npy", GOOD)]), "a", "duplicate"),
    "object": (header(canon("'|O'")), "a", "object"),
    "structured": (header(canon("[('x', '<f4'), ('y', '<f4')]", shape="(1,)")), "a",
                   "structured"),
    "subarray": (header(canon("('<f4', (2,))", shape="(1,)")), "a", "subarray"),
    "datetime": (header(canon("'<M8[D]'")), "a", "not supported"),
    "void": (header(canon("'|V8'", shape="(1,)")), "a", "not supported"),
    "bad_itemsize": (header(canon("'<f3'")), "a", "not a numpy dtype"),
    "negative_shape": (header(canon(shape="(-2,)")), "a", "shape"),
    "float_shape": (header(canon(shape="(2.0,)")), "a", "shape"),
    "bool_shape": (header(canon(shape="(True, 2)")), "a", "shape"),
    "shape_not_tuple": (header(canon(shape="[2]")), "a", "shape"),
    "fortran_not_bool": (header(canon(fortran="0")), "a", "fortran_order"),
    "extra_key": (header("{'descr': '<f4', 'fortran_order': False, 'shape': (2,), 'x': 1}"),
                  "a", "exactly"),
    "missing_key": (header("{'descr': '<f4', 'shape': (2,)}"), "a", "exactly"),
    "not_a_dict": (header("[1, 2]"), "a", "not a dict"),
    "not_a_literal": (header("__import__('os').system('true')"), "a", "literal"),
    "shape_claims_more": (one_member(f4_npy([1.0, 2.0], shape=(100,))), "a", "holds 8"),
    "shape_claims_less": (one_member(f4_npy(np.arange(8.0), shape=(2,))), "a", "holds 32"),
    "bad_magic": (one_member(b"\x93NUMPZ" + GOOD[6:]), "a", "magic"),
    "short_member": (one_member(b"\x93NUM"), "a", ".npy"),
    "version": (one_member(GOOD[:6] + b"\x04\x00" + GOOD[8:]), "a", "version 4.0"),
    "header_truncated": (one_member(GOOD[:40]), "a", "truncated"),
    "deflate_more": (deflated_size_lie(10, 20), "a", "more than"),
    "deflate_fewer": (deflated_size_lie(30, 20), "a", "fewer"),
    "deflate_corrupt": (corrupt_deflate_stream(), "a", "deflate"),
    "encrypted": (encrypted(), "a", "encrypted"),
    "bzip2": (one_member(GOOD, compression=zipfile.ZIP_BZIP2), "a", "method 12"),
    "lzma": (one_member(GOOD, compression=zipfile.ZIP_LZMA), "a", "method 14"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_malformed_archive_is_an_npz_error_naming_the_member(case):
    data, member, word = BAD[case]
    with pytest.raises(NpzError) as e:
        read_npz(data)
    assert word in str(e.value), str(e.value)
    assert e.value.member == member
    assert isinstance(e.value, ValueError)


def test_too_many_members_is_refused_before_the_directory_is_read():
    data = write_npz({"a": np.ones(1), "b": np.ones(1), "c": np.ones(1)})
    with pytest.raises(NpzError, match="3 members, more than max_members=2") as e:
        read_npz(data, max_members=2)
    assert e.value.member is None
    assert len(read_npz(data, max_members=3)) == 3


def test_overlapping_members_are_refused():
    # member a's data holds a complete stored member b; b's directory entry points there
    pb = npy_bytes(np.arange(4.0))
    record_b = zip_of([("b.npy", pb)])[:30 + 5 + len(pb)]
    pa = npy_bytes(np.frombuffer(record_b, np.uint8))
    data = bytearray(zip_of([("a.npy", pa), ("b.npy", pb)]))
    inside_a = data.find(record_b)
    assert 0 < inside_a < len(pa)
    struct.pack_into("<L", data, central_entries(bytes(data))[1] + 42, inside_a)
    with pytest.raises(NpzError, match="overlaps member 'a'") as e:
        read_npz(data)
    assert e.value.member == "b"


def test_bad_arguments_are_type_and_value_errors():
    data = write_npz({"a": np.ones(2)})
    with pytest.raises(TypeError, match="data must be"):
        read_npz("not bytes")
    with pytest.raises(TypeError, match="check must be"):
        read_npz(data, check=3)
    with pytest.raises(ValueError, match="max_members"):
        read_npz(data, max_members=-1)


# ---------------------------------------------------------------------------------------
# writer refusals


@pytest.mark.parametrize("arr, word", [
    (np.array([{}, 1], dtype=object), "object"),
    (np.zeros(2, [("x", "<f4"), ("y", "<i4")]), "only bool"),
    (np.zeros(2, "datetime64[s]"), "only bool"),
    (np.zeros(2, "V4"), "only bool"),
])
def test_writer_refuses_unsupported_dtypes_naming_the_array(arr, word):
    with pytest.raises(ValueError, match=r"arrays\['bad'\]") as e:
        write_npz({"ok": np.ones(1), "bad": arr})
    assert word in str(e.value)


@pytest.mark.parametrize("name", ["", "a/b", "a\\b", "a\0b", "\ud800"])
def test_writer_refuses_bad_names(name):
    with pytest.raises(ValueError, match="name"):
        npz_nbytes({name: np.ones(1)})


def test_writer_refuses_more_than_4_gib_without_allocating_it():
    huge = np.lib.stride_tricks.as_strided(np.zeros(1, np.uint8), (2**32,), (0,))
    with pytest.raises(ValueError, match=r"arrays\['huge'\].*4 GiB"):
        npz_nbytes({"huge": huge})
    half = np.lib.stride_tricks.as_strided(np.zeros(1, np.uint8), (2**31,), (0,))
    with pytest.raises(ValueError, match="4 GiB"):
        npz_nbytes({"a": half, "b": half})


def test_writer_argument_errors():
    arrays = {"a": np.ones(3)}
    with pytest.raises(TypeError, match="dict"):
        write_npz([("a", np.ones(3))])
    with pytest.raises(TypeError, match=r"arrays\['a'\] must be a numpy.ndarray"):
        write_npz({"a": [1, 2]})
    with pytest.raises(ValueError, match="needs"):
        write_npz_into(arrays, bytearray(npz_nbytes(arrays) - 1))
    with pytest.raises(TypeError, match="writable"):
        write_npz_into(arrays, bytes(1000))
    with pytest.raises(ValueError, match="contiguous"):
        write_npz_into(arrays, np.zeros(2000, np.uint8)[::2])


# ---------------------------------------------------------------------------------------
# fuzzing: nothing but a dict of arrays or NpzError, ever

SMALL = {"pos": np.arange(8, dtype=np.float32).reshape(2, 4),
         "tri": np.array([[0, 1, 2]], np.int32), "res": np.array([4, 4]),
         "f": np.asfortranarray(np.arange(6.0).reshape(2, 3)), "s": np.array("{}")}
BASES = [write_npz(SMALL), savez(SMALL), savez(SMALL, compressed=True),
         zip_of([(k + ".npy", npy_bytes(v)) for k, v in SMALL.items()], zipfile.ZIP_DEFLATED,
                b"a comment"),
         zip64_archive([(k + ".npy", npy_bytes(v)) for k, v in SMALL.items()])]


def read_or_npz_error(data):
    try:
        got = read_npz(data)
    except NpzError as e:
        assert e.member is None or isinstance(e.member, str)
        return
    assert isinstance(got, dict)
    assert all(isinstance(k, str) and isinstance(v, np.ndarray) for k, v in got.items())


@st.composite
def mutations(draw):
    data = bytearray(draw(st.sampled_from(BASES)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "set", "truncate", "insert", "delete"]))
        i = draw(st.integers(0, len(data)))
        if op == "flip" and i < len(data):
            data[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and i < len(data):
            data[i] = draw(st.sampled_from([0, 0xFF, 0x7F, 0x80, draw(st.integers(0, 255))]))
        elif op == "truncate":
            del data[i:]
        elif op == "insert":
            data[i:i] = draw(st.binary(min_size=1, max_size=16))
        elif op == "delete":
            del data[i:i + draw(st.integers(1, 16))]
    return bytes(data)


def test_bases_are_valid():
    for data in BASES:
        got = read_npz(data)
        for k, a in SMALL.items():
            assert_same(got[k], a)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=2048))
def test_arbitrary_bytes_give_arrays_or_npz_error(data):
    read_or_npz_error(data)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutations())
def test_mutated_archives_give_arrays_or_npz_error(data):
    read_or_npz_error(data)
