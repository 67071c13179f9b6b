"""A fast, strict, safe .npz codec (numpy's zip of .npy files) on the standard library.

The rendering service parses an .npz request body and encodes an .npz result on every
request; ``np.load``/``np.savez`` cost a ``zipfile`` object, an ``ast.literal_eval`` of every
.npy header and several copies of the data. This module reads and writes the same files with
``struct``, ``zlib``, ``re`` (and ``ast`` only for non-canonical headers) and numpy:

- :func:`read_npz` parses the zip central directory itself, returns **stored** members as
  zero-copy ``np.frombuffer`` views into the caller's buffer, inflates **deflated** members
  with an exact output bound, verifies every CRC-32, and lets the caller veto every member
  from its (name, dtype, shape) *before* any data is touched -- so a zip bomb costs nothing.
  Anything unreadable raises :class:`NpzError`, never ``struct.error``, ``zlib.error``,
  ``IndexError`` and the like.
- :func:`write_npz_into` writes a stored (uncompressed) archive into a caller's buffer with
  one copy of each array's data, every member's data 64-byte aligned from the start of the
  archive; :func:`npz_nbytes` says how big that buffer must be; :func:`write_npz` returns
  ``bytes``.

Accepted dtypes, both ways: bool, signed and unsigned integers, floats, complex, and the
fixed-width strings ``'S'`` (bytes) and ``'U'`` (unicode; the service sends JSON as a 0-d
``'<U...'`` array), in any byte order. Object, structured, subarray, void and datetime dtypes
are refused, so nothing read ever needs pickle.

Files written here are read by ``np.load(allow_pickle=False)`` bit-identically and pass
``zipfile.ZipFile.testzip()``; :func:`read_npz` reads ``np.savez``, ``np.savez_compressed``
(including the ZIP64 local headers numpy writes) and ``zipfile`` ``ZIP_STORED`` /
``ZIP_DEFLATED`` archives, with or without an archive comment.

This module imports nothing from glraster.
"""

from __future__ import annotations

import ast
import functools
import itertools
import math
import re
import struct
import zlib

import numpy as np

from glraster.errors import ArgumentError

__all__ = ["NpzError", "npz_nbytes", "read_npz", "write_npz", "write_npz_into"]


class NpzError(ValueError):
    """An unreadable .npz: .member is the member's name (without .npy) or None for the archive."""

    def __init__(self, member: str | None, message: str):
        self.member = member
        self.message = message
        where = "npz archive" if member is None else f"npz member {member!r}"
        super().__init__(f"{where}: {message}")

    def __reduce__(self):
        return type(self), (self.member, self.message)


# ---------------------------------------------------------------------------------------
# zip and .npy layouts (PKWARE APPNOTE 6.3; numpy.lib.format)

_LOCAL = struct.Struct("<4s5H3L2H")        # 30 bytes: local file header
_CENTRAL = struct.Struct("<4s6H3L5H2L")    # 46 bytes: central directory file header
_EOCD = struct.Struct("<4s4H2LH")          # 22 bytes: end of central directory record
_EOCD64_LOCATOR = struct.Struct("<4sLQL")  # 20 bytes: zip64 end of central directory locator
_EOCD64 = struct.Struct("<4sQ2H2L4Q")      # 56 bytes: zip64 end of central directory record
_EXTRA = struct.Struct("<HH")              # extra field block: header id, data size
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<L")
_U64 = struct.Struct("<Q")

_SIG_LOCAL = b"PK\x03\x04"
_SIG_CENTRAL = b"PK\x01\x02"
_SIG_EOCD = b"PK\x05\x06"
_SIG_EOCD64_LOCATOR = b"PK\x06\x07"
_SIG_EOCD64 = b"PK\x06\x06"
_MAX_COMMENT = 0xFFFF
_ZIP64_ID = 0x0001
_ALIGN_ID = 0xD935        # the "alignment" extra field of Android's zipalign
_FLAG_ENCRYPTED = 0x0001
_FLAG_STRONG_ENCRYPTION = 0x0040
_FLAG_UTF8 = 0x0800
_FLAG_MASKED_HEADERS = 0x2000
_STORED, _DEFLATED = 0, 8
_DOS_TIME, _DOS_DATE = 0, (0 << 9) | (1 << 5) | 1      # 1980-01-01 00:00:00
_VERSION = 20             # "2.0": stored and deflated members
_LIMIT32 = 0xFFFFFFFF     # largest archive written (no zip64 writing)

_NPY_MAGIC = b"\x93NUMPY"
_NPY_VERSIONS = {(1, 0): (_U16, 10), (2, 0): (_U32, 12), (3, 0): (_U32, 12)}
_MAX_HEADER = 65536       # .npy header dict bytes; an accepted dtype's header is < 1.5 KB
_MAX_NDIM = 64            # numpy's NPY_MAXDIMS
_ALIGN = 64               # member data offsets written are multiples of this
_ALLOWED_KINDS = frozenset("biufcUS")

# numpy's canonical header: "{'descr': '<f4', 'fortran_order': False, 'shape': (4096, 4), }"
# then spaces and a newline. Anything else goes through ast.literal_eval.
_INT = rb"(?:0|[1-9][0-9]{0,18})"
_CANONICAL = re.compile(
    rb"\{'descr': '([<>|=]?[A-Za-z][0-9]{0,10})', 'fortran_order': (True|False), "
    rb"'shape': \((|" + _INT + rb",|" + _INT + rb"(?:, " + _INT + rb")+,?)\), \}[ ]*\n?")
_DESCR = re.compile(r"[<>|=]?[biufcUS][1-9][0-9]{0,9}")
_SAFETY_NET = (struct.error, zlib.error, IndexError, KeyError, ValueError, TypeError,
               OverflowError, MemoryError, RecursionError, SyntaxError)


# ---------------------------------------------------------------------------------------
# reading

def read_npz(data, *, check=None, max_members: int = 64) -> dict[str, np.ndarray]:
    """Parse a whole .npz archive held in memory.

    data: bytes, bytearray or memoryview (any C-contiguous buffer) of the whole archive.
    Returns ``{name: array}`` with name = member filename without ``.npy``, in archive
    (central directory) order; every array has the dtype and shape of its .npy header.

    - Stored (method 0) members are zero-copy ``np.frombuffer`` views into ``data``: writeable
      iff ``data`` is writeable (bytearray, writable memoryview), and they keep ``data``
      alive (a bytearray cannot be resized while they exist). Fortran-order members are
      returned Fortran-ordered (``reshape(..., order='F')`` of the flat view).
    - Deflated (method 8) members are inflated with ``zlib.decompressobj(-15)`` with
      ``max_length`` = the size their .npy header implies (+1, to see an overrun); more or
      fewer bytes is an error. They are read-only views of the inflated ``bytes``.
    - The CRC-32 of every member is verified.

    check: optional ``check(name, dtype, shape)`` (``str``, ``np.dtype``, ``tuple`` of ints),
    called for every member, in archive order, after all .npy headers are read (for a
    deflated member only the few hundred bytes of stream that hold its header are inflated)
    and before the data of *any* member is inflated, checksummed or viewed. Whatever it raises
    propagates unchanged and nothing more is done: this is where the caller bounds sizes.
    max_members: more members than this is an error (checked before the directory is read).

    Raises NpzError (``.member`` names the member at fault, or None) for: not a zip, a
    truncated archive, no end-of-central-directory record, more than ``max_members``
    members, multi-disk archives, encrypted members, methods other than stored and
    deflated, member names that are duplicated, empty, not ending in ``.npy`` or containing
    ``/``, ``\\`` or NUL, overlapping members, a bad .npy magic or a version other than 1.0,
    2.0, 3.0, a header that is not a dict with exactly ``descr``, ``fortran_order`` and
    ``shape``, dtypes that are object, structured, subarray or of kind other than
    ``b i u f c U S``, shapes with non-int or negative entries, a data size other than
    ``prod(shape) * itemsize``, a bad deflate stream and a CRC mismatch. ZIP64 (extra field
    0x0001 in the central directory, ZIP64 end-of-central-directory record) is supported.
    TypeError / ValueError if ``data``, ``check`` or ``max_members`` themselves are wrong.
    """
    mv = _byte_view(data)
    if check is not None and not callable(check):
        raise TypeError(f"check must be a callable or None, got {type(check).__name__}")
    if isinstance(max_members, bool) or not isinstance(max_members, int) or max_members < 0:
        raise ArgumentError("max_members",
                            f"max_members must be an int >= 0, got {max_members!r}")
    src = data if type(data) is bytes or type(data) is bytearray else mv
    members = _read_directory(mv, src, max_members)
    if check is not None:
        for m in members:
            check(m[0], m[1], m[2])
    out = {}
    for m in members:
        try:
            out[m[0]] = _load_member(mv, src, m)
        except NpzError:
            raise
        except _SAFETY_NET as e:
            raise NpzError(m[0], f"unreadable data ({type(e).__name__}: {e})") from e
    return out


def _byte_view(buffer, name: str = "data", writable: bool = False) -> memoryview:
    """A flat unsigned-byte view of ``buffer`` (the argument called ``name``); TypeError or
    ValueError naming it when it is not a (writable) C-contiguous buffer."""
    try:
        mv = memoryview(buffer)
    except TypeError:
        raise TypeError(f"{name} must be a buffer (bytes, bytearray, memoryview, mmap, uint8 "
                        f"numpy array), got {type(buffer).__name__}") from None
    if writable and mv.readonly:
        raise TypeError(f"{name} must be a writable buffer, got a read-only "
                        f"{type(buffer).__name__}")
    if not mv.c_contiguous:
        raise ValueError(f"{name} must be a C-contiguous buffer")
    if mv.format != "B" or mv.ndim != 1:
        mv = mv.cast("B")
    return mv


def _read_directory(mv: memoryview, src, max_members: int) -> list[tuple]:
    """Every member's (name, dtype, shape, fortran, method, start, csize, hsize, crc),
    from the central directory and the .npy headers; touches no member data."""
    name = None
    try:
        cd_off, cd_size, count = _find_directory(mv, src, max_members)
        cd_end = cd_off + cd_size
        members, seen, spans = [], set(), []
        p = cd_off
        for _ in range(count):
            name = None
            if p + 46 > cd_end:
                raise NpzError(None, "central directory is truncated "
                               f"(entry at offset {p} runs past its end at {cd_end})")
            (sig, _made, _need, flags, method, _time, _date, crc, csize, usize, nlen, elen,
             clen, disk, _iattr, _eattr, off) = _CENTRAL.unpack_from(src, p)
            if sig != _SIG_CENTRAL:
                raise NpzError(None, f"bad central directory entry signature at offset {p}")
            q = p + 46 + nlen + elen + clen
            if q > cd_end:
                raise NpzError(None, f"central directory entry at offset {p} runs past the "
                               "end of the central directory")
            raw = bytes(src[p + 46:p + 46 + nlen])
            name = _member_name(raw, flags)
            if usize == _LIMIT32 or csize == _LIMIT32 or off == _LIMIT32 or disk == 0xFFFF:
                usize, csize, off, disk = _zip64_extra(
                    mv[p + 46 + nlen:p + 46 + nlen + elen], usize, csize, off, disk, name)
            if disk != 0:
                raise NpzError(name, f"member is on disk {disk}; multi-disk archives "
                               "are not supported")
            if flags & (_FLAG_ENCRYPTED | _FLAG_STRONG_ENCRYPTION | _FLAG_MASKED_HEADERS):
                raise NpzError(name, "member is encrypted (general purpose flags "
                               f"0x{flags:04x}); encrypted archives are not supported")
            if method != _STORED and method != _DEFLATED:
                raise NpzError(name, f"compression method {method} is not supported "
                               "(only 0 = stored and 8 = deflated)")
            if name in seen:
                raise NpzError(name, "duplicate member name")
            seen.add(name)
            start = _local_data_start(mv, src, off, raw, method, cd_off, name)
            if start + csize > cd_off:
                raise NpzError(name, f"member data ({csize} bytes at offset {start}) runs past "
                               f"the start of the central directory at {cd_off}")
            spans.append((off, start + csize, name))
            if method == _STORED:
                if csize != usize:
                    raise NpzError(name, f"stored member has compressed size {csize} != "
                                   f"uncompressed size {usize}")
                dtype, shape, fortran, hsize = _npy_header(mv[start:start + csize], name)
            else:
                dtype, shape, fortran, hsize = _npy_header(
                    _inflate_head(mv[start:start + csize], usize, name), name)
            nbytes = math.prod(shape) * dtype.itemsize
            if hsize + nbytes != usize:
                raise NpzError(name, f"header says dtype {dtype.str} shape {shape} = {nbytes} "
                               f"data bytes, but the member holds {usize - hsize}")
            members.append((name, dtype, shape, fortran, method, start, csize, hsize, crc))
            p = q
        name = None
        if p != cd_end:
            raise NpzError(None, f"central directory holds {cd_end - p} bytes after its "
                           f"{count} entries")
        if len(spans) > 1:
            spans.sort()
            for (_, end, a), (nxt, _, b) in itertools.pairwise(spans):
                if end > nxt:
                    raise NpzError(b, f"member overlaps member {a!r}")
        return members
    except NpzError:
        raise
    except _SAFETY_NET as e:
        raise NpzError(name, f"unreadable ({type(e).__name__}: {e})") from e


def _find_directory(mv: memoryview, src, max_members: int) -> tuple[int, int, int]:
    """(central directory offset, size in bytes, entry count), from the end records."""
    n = len(mv)
    if n < 22:
        raise NpzError(None, f"not a zip archive: {n} bytes is too short for the "
                       "end-of-central-directory record")
    pos = n - 22
    rec = _EOCD.unpack_from(src, pos)
    if rec[0] != _SIG_EOCD or rec[7] != 0:
        pos = -1
        lo = max(0, n - 22 - _MAX_COMMENT)
        hay = src if type(src) is not memoryview else mv[lo:].tobytes()
        base = 0 if type(src) is not memoryview else lo
        i = hay.rfind(_SIG_EOCD, lo - base, n - base - 18)
        while i >= 0:
            rec = _EOCD.unpack_from(hay, i)
            if base + i + 22 + rec[7] == n:
                pos = base + i
                break
            i = hay.rfind(_SIG_EOCD, lo - base, i)
        if pos < 0:
            raise NpzError(None, "not a zip archive or truncated: no end-of-central-directory "
                           "record in the last 65557 bytes")
    _, disk, cd_disk, n_disk, count, cd_size, cd_off, _ = rec
    limit = pos
    if pos >= 20 and mv[pos - 20:pos - 16] == _SIG_EOCD64_LOCATOR:
        _, loc_disk, rec64_off, disks = _EOCD64_LOCATOR.unpack_from(src, pos - 20)
        if loc_disk != 0 or disks > 1:
            raise NpzError(None, "multi-disk archives are not supported")
        if rec64_off + 56 > pos - 20:
            raise NpzError(None, f"ZIP64 end-of-central-directory record offset {rec64_off} "
                           "is past the locator")
        (sig, _size, _made, _need, disk, cd_disk, n_disk, count, cd_size,
         cd_off) = _EOCD64.unpack_from(src, rec64_off)
        if sig != _SIG_EOCD64:
            raise NpzError(None, "bad ZIP64 end-of-central-directory record signature")
        limit = rec64_off
    elif count == 0xFFFF or cd_size == _LIMIT32 or cd_off == _LIMIT32:
        raise NpzError(None, "end-of-central-directory record has ZIP64 markers but there "
                       "is no ZIP64 locator")
    if disk != 0 or cd_disk != 0 or n_disk != count:
        raise NpzError(None, "multi-disk archives are not supported")
    if count > max_members:
        raise NpzError(None, f"archive has {count} members, more than max_members="
                       f"{max_members}")
    if cd_off + cd_size > limit:
        raise NpzError(None, f"truncated: central directory ({cd_size} bytes at offset "
                       f"{cd_off}) runs past the end records at {limit}")
    return cd_off, cd_size, count


def _member_name(raw: bytes, flags: int) -> str:
    """The array name of member filename ``raw`` (without ``.npy``), validated."""
    try:
        full = raw.decode("utf-8" if flags & _FLAG_UTF8 else "cp437")
    except UnicodeDecodeError:
        raise NpzError(None, f"member name {raw!r} is not valid UTF-8") from None
    name = full.removesuffix(".npy")
    if name == full:
        raise NpzError(name, "member name does not end in .npy")
    if not name:
        raise NpzError(name, "member name is empty ('.npy')")
    if "/" in full or "\\" in full or "\0" in full:
        raise NpzError(name, "member name contains '/', '\\' or NUL")
    return name


def _zip64_extra(extra: memoryview, usize: int, csize: int, off: int, disk: int,
                 name: str) -> tuple[int, int, int, int]:
    """Replace the 0xFFFFFFFF (0xFFFF) fields by the values of the ZIP64 extra field."""
    i, n = 0, len(extra)
    while i + 4 <= n:
        hid, size = _EXTRA.unpack_from(extra, i)
        if i + 4 + size > n:
            break
        if hid == _ZIP64_ID:
            j, end = i + 4, i + 4 + size
            fields = [usize, csize, off]
            for k in range(3):
                if fields[k] == _LIMIT32:
                    if j + 8 > end:
                        raise NpzError(name, "ZIP64 extra field is too short")
                    fields[k] = _U64.unpack_from(extra, j)[0]
                    j += 8
            if disk == 0xFFFF:
                if j + 4 > end:
                    raise NpzError(name, "ZIP64 extra field is too short")
                disk = _U32.unpack_from(extra, j)[0]
            return fields[0], fields[1], fields[2], disk
        i += 4 + size
    raise NpzError(name, "central directory has ZIP64 markers (0xFFFFFFFF) but no ZIP64 "
                   "extra field")


def _local_data_start(mv: memoryview, src, off: int, raw, method: int, limit: int,
                      name: str) -> int:
    """Offset of the member's data, after its local header (checked against the central
    directory: signature, name, method, encryption)."""
    if off + 30 > limit:
        raise NpzError(name, f"local header offset {off} is past the data area")
    sig, _need, flags, lmethod, _t, _d, _crc, _cs, _us, nlen, elen = _LOCAL.unpack_from(src, off)
    if sig != _SIG_LOCAL:
        raise NpzError(name, f"bad local header signature at offset {off}")
    if flags & (_FLAG_ENCRYPTED | _FLAG_STRONG_ENCRYPTION):
        raise NpzError(name, f"member is encrypted (local header flags 0x{flags:04x})")
    if lmethod != method:
        raise NpzError(name, f"local header says compression method {lmethod}, central "
                       f"directory says {method}")
    if nlen != len(raw) or mv[off + 30:off + 30 + nlen] != raw:
        raise NpzError(name, "file name in the local header differs from the central "
                       "directory")
    return off + 30 + nlen + elen


def _inflate_head(comp: memoryview, usize: int, name: str) -> bytes:
    """The first bytes of a deflated member: enough for its whole .npy header."""
    want = min(usize, 12)
    d, out, pos, step = zlib.decompressobj(-15), b"", 0, 256
    header_known = False
    try:
        while True:
            while len(out) < want and pos < len(comp) and not d.eof:
                chunk = comp[pos:pos + step]
                out += d.decompress(chunk, want - len(out))
                pos += len(chunk) - len(d.unconsumed_tail)   # a tail: output bound reached
                step *= 4
            if header_known or len(out) < 10 or out[:6] != _NPY_MAGIC:
                return out
            fmt_prefix = _NPY_VERSIONS.get((out[6], out[7]))
            if fmt_prefix is None or len(out) < fmt_prefix[1]:
                return out
            fmt, prefix = fmt_prefix
            want = min(usize, prefix + min(fmt.unpack_from(out, 8)[0], _MAX_HEADER + 1))
            header_known = True
    except zlib.error as e:
        raise NpzError(name, f"corrupt deflate stream ({e})") from None


def _npy_header(head, name: str) -> tuple[np.dtype, tuple[int, ...], bool, int]:
    """(dtype, shape, fortran_order, header size in bytes) of the .npy file starting
    ``head`` (bytes or memoryview holding at least the whole header)."""
    n = len(head)
    if n < 10 or head[:6] != _NPY_MAGIC:
        raise NpzError(name, "not a .npy file (bad magic)" if n >= 6 else
                       f"not a .npy file ({n} bytes)")
    version = (head[6], head[7])
    fmt_prefix = _NPY_VERSIONS.get(version)
    if fmt_prefix is None:
        raise NpzError(name, f".npy format version {version[0]}.{version[1]} is not "
                       "supported (only 1.0, 2.0, 3.0)")
    fmt, prefix = fmt_prefix
    if n < prefix:
        raise NpzError(name, ".npy header is truncated")
    hlen = fmt.unpack_from(head, 8)[0]
    if hlen > _MAX_HEADER:
        raise NpzError(name, f".npy header of {hlen} bytes is longer than {_MAX_HEADER}")
    if prefix + hlen > n:
        raise NpzError(name, f".npy header of {hlen} bytes is truncated (member holds "
                       f"{n - prefix})")
    text = bytes(head[prefix:prefix + hlen])
    m = _CANONICAL.fullmatch(text)
    if m is not None:
        descr, fortran, dims = m.groups()
        dtype = _dtype(descr.decode("ascii"), name)
        shape = tuple(map(int, dims.rstrip(b",").split(b","))) if dims else ()
        fortran = fortran == b"True"
    else:
        dtype, shape, fortran = _literal_header(text, version, name)
    if len(shape) > _MAX_NDIM:
        raise NpzError(name, f"shape has {len(shape)} dimensions, more than {_MAX_NDIM}")
    return dtype, shape, fortran, prefix + hlen


def _literal_header(text: bytes, version: tuple[int, int], name: str):
    """A non-canonical .npy header through ast.literal_eval, validated like the fast path."""
    try:
        d = ast.literal_eval(text.decode("utf-8" if version == (3, 0) else "latin1"))
    except UnicodeDecodeError:
        raise NpzError(name, ".npy header is not valid UTF-8") from None
    except (ValueError, SyntaxError, TypeError, MemoryError, RecursionError) as e:
        raise NpzError(name, f".npy header is not a Python literal ({type(e).__name__})") \
            from None
    if not isinstance(d, dict):
        raise NpzError(name, f".npy header is not a dict (got {type(d).__name__})")
    keys = set(d) if all(isinstance(k, str) for k in d) else None
    if keys != {"descr", "fortran_order", "shape"}:
        raise NpzError(name, ".npy header keys must be exactly descr, fortran_order, shape; "
                       f"got {sorted(map(repr, d))}")
    descr, fortran, shape = d["descr"], d["fortran_order"], d["shape"]
    if isinstance(descr, list):
        raise NpzError(name, "structured dtypes (fields) are not supported")
    if not isinstance(descr, str):
        raise NpzError(name, f"dtype descr {descr!r} is not supported (subarray or "
                       "non-string descr)")
    if not isinstance(fortran, bool):
        raise NpzError(name, f"fortran_order must be True or False, got {fortran!r}")
    if not isinstance(shape, tuple) or not all(
            type(s) is int and s >= 0 for s in shape):
        raise NpzError(name, f"shape must be a tuple of ints >= 0, got {shape!r}")
    return _dtype(descr, name), shape, fortran


def _dtype(descr: str, name: str) -> np.dtype:
    try:
        return _checked_dtype(descr)
    except ValueError as e:
        raise NpzError(name, str(e)) from None


@functools.lru_cache(maxsize=256)
def _checked_dtype(descr: str) -> np.dtype:
    """np.dtype(descr) for an accepted simple descr such as '<f4', '|b1', '<U20'."""
    if _DESCR.fullmatch(descr) is None:
        if "O" in descr:
            raise ValueError(f"object dtype {descr!r} is not supported")
        raise ValueError(f"dtype {descr!r} is not supported (only bool, int, uint, float, "
                         "complex, 'S' and 'U', as '<f4', '|b1', '<U20', ...)")
    try:
        dtype = np.dtype(descr)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"dtype {descr!r} is not a numpy dtype") from None
    if dtype.kind not in _ALLOWED_KINDS or dtype.fields is not None or dtype.subdtype:
        raise ValueError(f"dtype {descr!r} (kind {dtype.kind!r}) is not supported")
    if dtype.itemsize == 0:
        raise ValueError(f"dtype {descr!r} has itemsize 0")
    return dtype


def _load_member(mv: memoryview, src, m: tuple) -> np.ndarray:
    """The array of member m = (name, dtype, shape, fortran, method, start, csize, hsize,
    crc), CRC verified."""
    name, dtype, shape, fortran, method, start, csize, hsize, crc = m
    nbytes = csize - hsize if method == _STORED else None
    if method == _STORED:
        if zlib.crc32(mv[start:start + csize]) != crc:
            raise NpzError(name, "CRC-32 mismatch: the member's data is corrupt")
        buf, offset = src, start + hsize
    else:
        d = zlib.decompressobj(-15)
        nbytes = math.prod(shape) * dtype.itemsize
        want = hsize + nbytes
        try:
            buf = d.decompress(mv[start:start + csize], want + 1)
        except zlib.error as e:
            raise NpzError(name, f"corrupt deflate stream ({e})") from None
        if len(buf) > want:
            raise NpzError(name, f"deflated member decompresses to more than the {want} "
                           "bytes its header implies")
        if len(buf) < want or not d.eof:
            raise NpzError(name, f"deflated member decompresses to {len(buf)} bytes, fewer "
                           f"than the {want} its header implies, or its stream is truncated")
        if d.unused_data:
            raise NpzError(name, f"{len(d.unused_data)} bytes after the end of the deflate "
                           "stream")
        if zlib.crc32(buf) != crc:
            raise NpzError(name, "CRC-32 mismatch: the member's data is corrupt")
        offset = hsize
    arr = np.frombuffer(buf, dtype, nbytes // dtype.itemsize, offset)
    if len(shape) != 1:
        arr = arr.reshape(shape, order="F" if fortran else "C")
    return arr


# ---------------------------------------------------------------------------------------
# writing

def npz_nbytes(arrays: dict) -> int:
    """Exact size in bytes of the stored .npz that write_npz_into writes for ``arrays``
    (``{name: np.ndarray}``, names without ``.npy``). Raises like write_npz_into."""
    return _plan(arrays)[1]


def write_npz_into(arrays: dict, out) -> int:
    """Write ``arrays`` as an uncompressed (stored) .npz into the buffer ``out``.

    arrays: ``{name: np.ndarray}`` in member order; names are non-empty ``str`` without
    ``/``, ``\\`` or NUL (``.npy`` is appended). dtypes: bool, ints, uints, floats, complex,
    ``'S'``, ``'U'`` in any byte order; any shape, 0-d included (the service's JSON is a 0-d
    ``'<U...'`` array).
    out: a writable C-contiguous buffer -- bytearray, memoryview, mmap, uint8 numpy array --
    of at least ``npz_nbytes(arrays)`` bytes; bytes after the archive are left untouched.
    Returns the number of bytes written (``npz_nbytes(arrays)``).

    Each array's data is copied once, straight into ``out`` (a non-contiguous array is
    gathered by that same copy); an F-contiguous, not C-contiguous array is written in
    Fortran order with ``fortran_order: True``. Every member's data starts at a multiple of
    64 bytes from the start of the archive (the local header carries a 0xD935 "alignment"
    extra field as padding and the .npy header is padded to 64 bytes as numpy pads it), so
    read_npz of an ``out`` that is itself 64-byte aligned returns 64-byte aligned arrays.
    .npy headers are version 1.0 (with these dtypes a header is always < 65536 bytes).
    Dates are 1980-01-01 00:00. No ZIP64 is written, so a member or the whole archive must
    not exceed 4 GiB - 1, and there are at most 65534 members.

    Raises TypeError if ``arrays`` is not a dict of numpy arrays keyed by ``str`` or ``out``
    is not a writable buffer, ValueError (naming the array) for an unsupported dtype
    (object, structured, ...), a bad name or an oversized archive, and ValueError if ``out``
    is too small.
    """
    members, total = _plan(arrays)
    mv = _byte_view(out, "out", writable=True)
    if len(mv) < total:
        raise ArgumentError("out", f"out has {len(mv)} bytes, the archive needs {total}")
    u8 = np.frombuffer(mv, np.uint8, total)
    crcs = []
    for name_b, flags, off, extra, header, arr, fortran in members:
        start = off + _LOCAL.size + len(name_b) + len(extra)
        data = start + len(header)
        nbytes = arr.nbytes
        mv[start:data] = header
        if nbytes:
            dst = u8[data:data + nbytes].view(arr.dtype)
            if arr.ndim != 1:
                dst = dst.reshape(arr.shape, order="F" if fortran else "C")
            np.copyto(dst, arr, casting="no")
        crc = zlib.crc32(mv[start:data + nbytes])
        crcs.append(crc)
        _LOCAL.pack_into(mv, off, _SIG_LOCAL, _VERSION, flags, _STORED, _DOS_TIME, _DOS_DATE,
                         crc, len(header) + nbytes, len(header) + nbytes, len(name_b),
                         len(extra))
        p = off + _LOCAL.size
        mv[p:p + len(name_b)] = name_b
        mv[p + len(name_b):start] = extra
    tail = _central_directory(members, crcs, total)
    mv[total - len(tail):total] = tail
    return total


def write_npz(arrays: dict) -> bytes:
    """write_npz_into into a fresh buffer; returns the archive as ``bytes``.

    The same archive, byte for byte, as write_npz_into. The data of C- or F-contiguous
    arrays is copied once (``bytes.join`` of the arrays' own buffers); others are made
    contiguous first. For large results reuse a buffer with write_npz_into instead.
    """
    members, total = _plan(arrays)
    pieces, crcs = [], []
    for name_b, flags, _off, extra, header, arr, fortran in members:
        data = arr.T if fortran else np.ascontiguousarray(arr)
        flat = data.reshape(-1).view(np.uint8)
        crc = zlib.crc32(flat, zlib.crc32(header))
        crcs.append(crc)
        size = len(header) + arr.nbytes
        pieces += (_LOCAL.pack(_SIG_LOCAL, _VERSION, flags, _STORED, _DOS_TIME, _DOS_DATE,
                               crc, size, size, len(name_b), len(extra)),
                   name_b, extra, header, flat)
    pieces.append(_central_directory(members, crcs, total))
    return b"".join(pieces)


def _plan(arrays) -> tuple[list[tuple], int]:
    """Validate ``arrays`` and lay the archive out: a list of (name bytes, flags, local header
    offset, extra field, .npy header, array, fortran) and the total size."""
    if not isinstance(arrays, dict):
        raise TypeError(f"arrays must be a dict of name -> numpy array, got "
                        f"{type(arrays).__name__}")
    if len(arrays) > 0xFFFE:
        raise ArgumentError(
            "arrays", f"arrays has {len(arrays)} entries, more than 65534 (no ZIP64)")
    members, off, cd_size = [], 0, 0
    for name, arr in arrays.items():
        if not isinstance(name, str):
            raise TypeError(f"array names must be str, got {name!r}")
        if not isinstance(arr, np.ndarray):
            raise TypeError(f"arrays[{name!r}] must be a numpy.ndarray, got "
                            f"{type(arr).__name__}")
        if not name or "/" in name or "\\" in name or "\0" in name:
            raise ArgumentError(
                "arrays", f"array name {name!r} must be non-empty, without '/', '\\' "
                         "or NUL")
        full = name + ".npy"
        if full.isascii():
            name_b, flags = full.encode("ascii"), 0
        else:
            try:
                name_b, flags = full.encode("utf-8"), _FLAG_UTF8
            except UnicodeEncodeError:
                raise ArgumentError(
                    "arrays", f"array name {name!r} is not encodable as UTF-8") from None
        if len(name_b) > 0xFFFF:
            raise ArgumentError(
                "arrays", f"array name {name[:40]!r}... is too long for a zip member name")
        dt = arr.dtype
        if dt.hasobject:
            raise ArgumentError(
                "arrays", f"arrays[{name!r}] has object dtype {dt}; object arrays are not "
                          "supported (they would need pickle)")
        if dt.fields is not None or dt.subdtype is not None or dt.kind not in _ALLOWED_KINDS:
            raise ArgumentError(
                "arrays", f"arrays[{name!r}] has dtype {dt}; only bool, int, uint, float, "
                          "complex, 'S' and 'U' dtypes without fields are supported")
        if dt.itemsize == 0:
            raise ArgumentError("arrays", f"arrays[{name!r}] has dtype {dt} of itemsize 0")
        fortran = arr.ndim > 1 and arr.flags.f_contiguous and not arr.flags.c_contiguous
        header = _npy_header_bytes(dt.str, fortran, arr.shape)
        pad = -(off + _LOCAL.size + len(name_b)) % _ALIGN
        if 0 < pad < 6:
            pad += _ALIGN
        extra = b"" if pad == 0 else _EXTRA.pack(_ALIGN_ID, pad - 4) + _U16.pack(_ALIGN) \
            + bytes(pad - 6)
        size = len(header) + arr.nbytes
        if size > _LIMIT32 - 1:
            raise ArgumentError(
                "arrays", f"arrays[{name!r}] needs {size} bytes, more than 4 GiB - 1 "
                          "(ZIP64 is not written)")
        members.append((name_b, flags, off, extra, header, arr, fortran))
        off += _LOCAL.size + len(name_b) + pad + size
        cd_size += _CENTRAL.size + len(name_b)
    total = off + cd_size + _EOCD.size
    if total > _LIMIT32:
        raise ArgumentError("arrays", f"arrays need a {total}-byte archive, more than 4 GiB - 1 "
                                      "(ZIP64 is not written)")
    return members, total


def _npy_header_bytes(descr: str, fortran: bool, shape: tuple) -> bytes:
    """numpy's canonical version-1.0 header, padded with spaces and a newline to a multiple
    of 64 bytes (magic and length included)."""
    text = f"{{'descr': {descr!r}, 'fortran_order': {fortran!r}, 'shape': {shape!r}, }}"
    hlen = len(text) + 1 + (-(10 + len(text) + 1) % _ALIGN)
    return b"".join((_NPY_MAGIC, b"\x01\x00", _U16.pack(hlen), text.encode("latin1"),
                     b" " * (hlen - len(text) - 1), b"\n"))


def _central_directory(members: list[tuple], crcs: list[int], total: int) -> bytes:
    """Central directory entries and the end-of-central-directory record."""
    parts = []
    for (name_b, flags, off, _extra, header, arr, _f), crc in zip(members, crcs):
        size = len(header) + arr.nbytes
        parts += (_CENTRAL.pack(_SIG_CENTRAL, _VERSION, _VERSION, flags, _STORED, _DOS_TIME,
                                _DOS_DATE, crc, size, size, len(name_b), 0, 0, 0, 0, 0, off),
                  name_b)
    cd = b"".join(parts)
    cd_off = total - len(cd) - _EOCD.size
    return cd + _EOCD.pack(_SIG_EOCD, 0, 0, len(members), len(members), len(cd), cd_off, 0)
