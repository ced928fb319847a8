"""gRPC between the actor and the learner, with bytes payloads and no generated code.

Every call is unary: request and response are `pack(header: dict, blob: bytes)` - a JSON header and an
opaque blob (a tar of a saved learner, an npz of transitions). Every call has a deadline; a handler that
raises answers {"error": ...} instead of killing the server. The first call of a connection is `Hello`,
which compares PROTOCOL (a mismatch is refused with both versions named).
"""

from __future__ import annotations

import io
import json
import struct
import tarfile
from pathlib import Path
from typing import Callable

from accrue.errors import AccrueError

PROTOCOL = 1
SERVICE = "accrue.robot.Learner"
MAX_MESSAGE = 512 * 1024 * 1024
_OPTIONS = [("grpc.max_send_message_length", MAX_MESSAGE), ("grpc.max_receive_message_length", MAX_MESSAGE)]

Handler = Callable[[dict, bytes], tuple[dict, bytes]]


def _grpc():
    import os

    # gRPC's C core logs failures it also raises; accrue reports them itself, in one line
    os.environ.setdefault("GRPC_VERBOSITY", "NONE")
    import grpc

    return grpc


class PeerDown(Exception):
    """The peer did not answer in time, or is not there."""


def pack(header: dict, blob: bytes = b"") -> bytes:
    head = json.dumps(header, sort_keys=True).encode()
    return struct.pack(">I", len(head)) + head + blob


def unpack(data: bytes) -> tuple[dict, bytes]:
    if len(data) < 4:
        raise AccrueError("learner transport: truncated message")
    (n,) = struct.unpack(">I", data[:4])
    return json.loads(data[4 : 4 + n]), data[4 + n :]


def tar_dir(path: Path) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w") as tar:
        for p in sorted(Path(path).rglob("*")):
            if p.is_file():
                tar.add(p, arcname=str(p.relative_to(path)), recursive=False)
    return buf.getvalue()


def untar(blob: bytes, dest: Path) -> Path:
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(blob), mode="r") as tar:
        tar.extractall(dest, filter="data")
    return dest


def serve(handlers: dict[str, Handler], address: str, workers: int = 8):
    """Start a gRPC server; returns (server, bound port). Workers leave headroom for a reconnecting actor."""
    from concurrent import futures

    grpc = _grpc()

    def wrap(fn: Handler):
        def call(request: bytes, context) -> bytes:
            try:
                header, blob = unpack(request)
                out, out_blob = fn(header, blob)
            except Exception as exc:  # noqa: BLE001 - a bad request must not kill the learner
                return pack({"error": f"{type(exc).__name__}: {exc}"})
            return pack(out, out_blob)

        return grpc.unary_unary_rpc_method_handler(call)

    server = grpc.server(futures.ThreadPoolExecutor(max_workers=workers), options=_OPTIONS)
    server.add_generic_rpc_handlers(
        (grpc.method_handlers_generic_handler(SERVICE, {name: wrap(fn) for name, fn in handlers.items()}),)
    )
    try:
        port = server.add_insecure_port(address)
    except RuntimeError:
        port = 0
    if port == 0:
        raise AccrueError(f"learner: cannot listen on {address!r} (expected HOST:PORT with a free port)")
    server.start()
    return server, port


class Peer:
    def __init__(self, address: str):
        grpc = _grpc()
        self.address = address
        self._grpc = grpc
        self.channel = grpc.insecure_channel(address, options=_OPTIONS)

    def call(self, method: str, header: dict, blob: bytes = b"", timeout: float = 5.0) -> tuple[dict, bytes]:
        fn = self.channel.unary_unary(f"/{SERVICE}/{method}")
        try:
            data = fn(pack(header, blob), timeout=timeout)
        except self._grpc.RpcError as exc:
            code = exc.code().name if hasattr(exc, "code") else "?"
            raise PeerDown(f"{method} to {self.address}: {code}") from None
        out, out_blob = unpack(data)
        if "error" in out:
            raise AccrueError(f"learner at {self.address} refused {method}: {out['error']}")
        return out, out_blob

    def close(self) -> None:
        self.channel.close()
