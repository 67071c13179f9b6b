"""The worker pipe's framing: frames written by the worker's side are read back exactly by
the event loop's :class:`FrameProtocol` and the other way round, whatever their size and
however the bytes are split across reads."""

from __future__ import annotations

import asyncio
import socket
import threading

import numpy as np
import pytest
import uvloop

from glraster.service import wire

SIZES = [0, 1, 100, (1 << 18) - 200, 1 << 18, (1 << 18) + 1, 3_000_001]

# the server runs on uvloop (uvicorn's choice when it is installed); asyncio's own loop too
LOOPS = {"uvloop": uvloop.new_event_loop, "asyncio": asyncio.new_event_loop}


def _run(loop_name, coro):
    loop = LOOPS[loop_name]()
    try:
        return loop.run_until_complete(coro)
    finally:
        loop.close()


def _payload(n: int, seed: int) -> bytes:
    return np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()


@pytest.mark.parametrize("loop_name", sorted(LOOPS))
def test_worker_frames_arrive_whole_and_in_order_on_the_event_loop(loop_name):
    """Small frames come out of the staging buffer, large ones are read straight into
    their own array; several frames in one read and one frame over many reads alike."""
    worker_end, server_end = socket.socketpair()
    frames = [({"n": i, "size": n}, _payload(n, i)) for i, n in enumerate(SIZES)]

    def worker():
        for header, body in frames:
            wire.send(worker_end, header, body)
        worker_end.close()

    async def server():
        loop = asyncio.get_running_loop()
        _, proto = await loop.create_unix_connection(wire.FrameProtocol, sock=server_end)
        t = threading.Thread(target=worker)
        t.start()
        got = [await proto.expect() for _ in frames]
        with pytest.raises(wire.Died):
            await proto.expect()          # the worker closed its end
        t.join()
        return got

    got = _run(loop_name, server())
    for (header, body), (h, b) in zip(frames, got):
        assert h == header
        assert bytes(b) == body


@pytest.mark.parametrize("loop_name", sorted(LOOPS))
def test_server_frames_are_read_by_the_worker_into_its_reused_buffer(loop_name):
    worker_end, server_end = socket.socketpair()
    frames = [(("rasterize", {"n": i}), _payload(n, 100 + i)) for i, n in enumerate(SIZES)]

    async def server():
        loop = asyncio.get_running_loop()
        transport, proto = await loop.create_unix_connection(wire.FrameProtocol,
                                                             sock=server_end)
        for header, body in frames:
            proto.send(header, body)
        proto.send(("stop",))
        await asyncio.sleep(0)
        return transport

    received = []

    def worker():
        receiver = wire.Receiver(worker_end)
        while True:
            header, body = receiver.recv()
            if header == ("stop",):
                break
            received.append((header, bytes(body)))   # the view is valid until the next recv

    t = threading.Thread(target=worker)
    t.start()

    async def main():
        transport = await server()
        await asyncio.get_running_loop().run_in_executor(None, t.join, 30)
        transport.close()

    _run(loop_name, main())
    assert received == frames


def test_receiver_reports_a_closed_pipe_as_eof():
    a, b = socket.socketpair()
    b.sendall(wire.PREFIX.pack(10, 0) + b"abc")      # a frame cut short
    b.close()
    with pytest.raises(EOFError):
        wire.Receiver(a).recv()
