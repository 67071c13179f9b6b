"""The framing on a worker's socket pair: one frame per message, in both directions.

A frame is a 12-byte prefix (header length as a big-endian uint32, body length as a
uint64), the pickled header and the raw body bytes:

- server -> worker: header ``(kind, meta)`` and the request body, or ``("stop",)``;
- worker -> server: ``("ready", info)`` / ``("failed", message)`` once, then per job the
  header ``(status, content_type, headers)`` and the result body.

Only the server's own process writes headers the worker unpickles and vice versa; request
data travels in bodies, which are never unpickled. One frame is one ``sendmsg`` of its
three parts (no concatenation), read on the worker's side into one reused buffer and on
the server's side by :class:`FrameProtocol` straight into the body's final array, so a
message costs the two processes one write and about one read each, whatever its size.
"""

from __future__ import annotations

import asyncio
import pickle
import socket
import struct

import numpy as np

PREFIX = struct.Struct("!IQ")     # header bytes, body bytes
_STAGING = 1 << 18                # bytes read per call while no large body is being read
_KEEP = 1 << 24                   # the worker keeps a body buffer up to this size


def pack(header) -> bytes:
    return pickle.dumps(header, protocol=pickle.HIGHEST_PROTOCOL)


def send(sock: socket.socket, header, body=b"") -> None:
    """Write one frame on a blocking socket (the worker's side)."""
    head = pack(header)
    parts = [PREFIX.pack(len(head), len(body)), head, memoryview(body).cast("B")]
    while parts:
        sent = sock.sendmsg(parts)
        while parts and sent >= len(parts[0]):
            sent -= len(parts[0])
            parts.pop(0)
        if parts and sent:
            parts[0] = memoryview(parts[0])[sent:]


class Receiver:
    """Reads frames from a blocking socket (the worker's side), one ``recv_into`` per frame
    where it fits the buffer. A body is a memoryview into that buffer, which this object
    reuses: it is valid until the next :meth:`recv`. A read may bring the start of the next
    frame (the pool sends a worker its next job while it renders one); that is kept for
    the next call."""

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self._buf = bytearray(_STAGING)
        self._have = 0            # bytes at the start of _buf not yet handed out
        self._next = 0            # where the next frame starts in _buf

    def _read(self, need: int) -> None:
        """Until ``_buf[_next:]`` holds ``need`` bytes."""
        if self._next + need > len(self._buf):       # move the rest to the front (or grow)
            rest = self._have - self._next
            buf = bytearray(max(need, _STAGING)) if need > len(self._buf) else self._buf
            buf[:rest] = self._buf[self._next:self._have]
            self._buf, self._have, self._next = buf, rest, 0
        view = memoryview(self._buf)
        while self._have - self._next < need:
            n = self.sock.recv_into(view[self._have:])
            if n == 0:
                raise EOFError("the server closed the pipe")
            self._have += n

    def recv(self):
        """``(header, body)``; EOFError when the other side has closed."""
        if self._next == self._have:
            self._have = self._next = 0
        if len(self._buf) > _KEEP and self._have == 0:
            self._buf = bytearray(_STAGING)              # let a big one go
        self._read(PREFIX.size)
        head_len, body_len = PREFIX.unpack_from(self._buf, self._next)
        self._read(PREFIX.size + head_len + body_len)
        start = self._next + PREFIX.size
        header = pickle.loads(memoryview(self._buf)[start:start + head_len])
        body = memoryview(self._buf)[start + head_len:start + head_len + body_len]
        self._next = start + head_len + body_len
        return header, body


class Died(Exception):
    """The worker's pipe closed (the process died)."""


class FrameProtocol(asyncio.BufferedProtocol):
    """The server's end of a worker's socket pair, on the event loop.

    :meth:`send` writes a frame; :meth:`expect` returns a future for the next frame
    ``(header, body)`` (body: ``bytes`` when small, else a memoryview of a NumPy buffer
    of its own, which the HTTP response may hold as long as it needs). Small frames are
    parsed out of a staging buffer; the bytes of a large body are read by the socket
    straight into their array. The future fails with :class:`Died` when the pipe closes.
    """

    def __init__(self):
        self.transport = None
        self._staging = bytearray(_STAGING)
        self._staged = 0                    # bytes held in _staging
        self._head = None                   # the header of a frame whose body is being read
        self._body = None                   # (array, bytes read) of a large body
        self._frames = []                   # complete frames nobody has asked for yet
        self._waiter = None
        self._closed = False

    # -- the transport's side --------------------------------------------------------------
    def connection_made(self, transport):
        self.transport = transport

    def get_buffer(self, sizehint):
        if self._body is not None:
            array, filled = self._body
            return memoryview(array)[filled:]
        return memoryview(self._staging)[self._staged:]

    def buffer_updated(self, nbytes):
        if self._body is not None:
            array, filled = self._body
            filled += nbytes
            if filled < len(array):
                self._body = (array, filled)
                return
            self._body = None
            self._deliver(self._head, memoryview(array))
            return
        self._staged += nbytes
        self._parse()

    def _parse(self) -> None:
        data = memoryview(self._staging)
        start = 0
        while self._staged - start >= PREFIX.size:
            head_len, body_len = PREFIX.unpack_from(data, start)
            head_end = start + PREFIX.size + head_len
            if head_len > _STAGING - PREFIX.size:
                self._fail(Died(f"a header of {head_len} bytes from the worker"))
                return
            if self._staged < head_end:
                break
            if head_end + body_len <= self._staged:          # the whole frame is here
                header = pickle.loads(data[start + PREFIX.size:head_end])
                self._deliver(header, bytes(data[head_end:head_end + body_len]))
                start = head_end + body_len
                continue
            if body_len <= _STAGING - (head_end - start):
                break                                       # small: wait for the rest
            # large: read the rest of the body straight into its own array
            header = pickle.loads(data[start + PREFIX.size:head_end])
            array = np.empty(body_len, np.uint8)
            have = self._staged - head_end
            array[:have] = np.frombuffer(data[head_end:self._staged], np.uint8)
            self._head, self._body = header, (array, have)
            start = self._staged
            break
        if start:
            rest = self._staged - start
            data[:rest] = data[start:self._staged]
            self._staged = rest

    def connection_lost(self, exc):
        self._closed = True
        self._fail(Died("the worker closed its pipe"))

    def eof_received(self):
        return False

    # -- the slot's side ------------------------------------------------------------------
    def send(self, header, body=b"") -> None:
        head = pack(header)
        self.transport.writelines([PREFIX.pack(len(head), len(body)), head, body])

    def expect(self) -> asyncio.Future:
        """A future for the next frame from the worker."""
        fut = asyncio.get_running_loop().create_future()
        if self._frames:
            fut.set_result(self._frames.pop(0))
        elif self._closed:
            fut.set_exception(Died("the worker closed its pipe"))
        else:
            self._waiter = fut
        return fut

    @property
    def closed(self) -> bool:
        """The pipe has closed (the worker exited or died)."""
        return self._closed

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()

    def _deliver(self, header, body) -> None:
        waiter, self._waiter = self._waiter, None
        if waiter is not None and not waiter.done():
            waiter.set_result((header, body))
        else:
            self._frames.append((header, body))

    def _fail(self, exc) -> None:
        waiter, self._waiter = self._waiter, None
        if waiter is not None and not waiter.done():
            waiter.set_exception(exc)
        if self.transport is not None:
            self.transport.close()
