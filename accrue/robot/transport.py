"""gRPC between the actor and the learner, with bytes payloads and no generated code.

Every call is unary: request and response are `pack(header: dict, blob: bytes)` - a JSON header and an
opaque blob (a tar of a saved learner, an npz of transitions). Every call has a deadline; a handler that
raises answers {"error": ...} instead of killing the server. The first call of a connection is `Hello`,
which compares PROTOCOL (a mismatch is refused with both versions named).

Every call carries the link token (accrue.robot.link_auth) as metadata; the server compares it in constant
time before any handler runs and answers a call without it, or with another, UNAUTHENTICATED. With a
certificate and key the server speaks TLS; a Peer given a CA file verifies the learner's certificate.
"""

from __future__ import annotations

import hmac
import io
import json
import re
import struct
import tarfile
from pathlib import Path
from typing import Callable

from accrue.errors import AccrueError
from accrue.robot.link_auth import METADATA_KEY, check_pem, parse_address

PROTOCOL = 2  # 2: the link token on every call, version_floor at Init
SERVICE = "accrue.robot.Learner"
MAX_MESSAGE = 512 * 1024 * 1024
_OPTIONS = [("grpc.max_send_message_length", MAX_MESSAGE), ("grpc.max_receive_message_length", MAX_MESSAGE)]
# gRPC binds with SO_REUSEPORT by default, so a second learner on a port in use would start and share it
_SERVER_OPTIONS = [*_OPTIONS, ("grpc.so_reuseport", 0)]

Handler = Callable[[dict, bytes], tuple[dict, bytes]]


def _grpc():
    import os

    # gRPC's C core logs failures it also raises; accrue reports them itself, in one line
    os.environ.setdefault("GRPC_VERBOSITY", "NONE")
    import grpc

    return grpc


class PeerDown(Exception):
    """The peer did not answer in time, or is not there."""


class LinkRefused(PeerDown, AccrueError):
    """The learner refused this actor: `reason` "token" (it answered UNAUTHENTICATED or PERMISSION_DENIED:
    this actor's link token is not the learner's) or "tls" (the TLS handshake failed: the learner's
    certificate is not the one robot.link.tls.ca trusts, or one end speaks no TLS). Calling again with the
    same token and CA cannot succeed, unlike a PeerDown."""

    def __init__(self, message: str, reason: str = "token"):
        super().__init__(message)
        self.reason = reason


# how gRPC's details name a failed TLS handshake (it reports it as UNAVAILABLE, like a learner not there)
_TLS_FAILED = re.compile(r"(?i)(?:ssl|tls) handshake failed|CERTIFICATE_VERIFY_FAILED|WRONG_VERSION_NUMBER")


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


def tls_pair(cert: Path, key: Path) -> tuple[bytes, bytes]:
    """(key PEM, certificate PEM) for the server, checked before gRPC sees them: gRPC reports a bad pair only
    as an address it cannot listen on. Not PEM, the other kind, an encrypted key or a key that is not the
    certificate's is one AccrueError line naming both files."""
    bad = f"learner link: --tls-cert {cert} and --tls-key {key} are not a usable PEM pair"
    try:
        cert_pem = check_pem(cert, "certificate", "--tls-cert")
        key_pem = check_pem(key, "key", "--tls-key")
    except AccrueError as exc:
        raise AccrueError(f"{bad} ({exc})") from None
    try:
        from cryptography import x509
        from cryptography.exceptions import UnsupportedAlgorithm
        from cryptography.hazmat.primitives import serialization
    except ImportError:  # the PEM checks above are what can be done without it
        return key_pem, cert_pem
    try:
        public = x509.load_pem_x509_certificate(cert_pem).public_key()
    except ValueError as exc:
        raise AccrueError(f"{bad} ({cert} does not parse as a certificate: {exc})") from None
    try:
        private = serialization.load_pem_private_key(key_pem, password=None)
    except TypeError:
        raise AccrueError(f"{bad} ({key} is encrypted; give it without a passphrase, mode 0600)") from None
    except (ValueError, UnsupportedAlgorithm) as exc:
        raise AccrueError(f"{bad} ({key} does not parse as a private key: {exc})") from None
    der = serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo
    if private.public_key().public_bytes(*der) != public.public_bytes(*der):
        raise AccrueError(f"{bad} (the key is not the certificate's)")
    return key_pem, cert_pem


def serve(
    handlers: dict[str, Handler],
    address: str,
    workers: int = 8,
    *,
    token: str,
    tls_cert: Path | None = None,
    tls_key: Path | None = None,
    on_refused: Callable[[str, str], None] | None = None,
):
    """Start a gRPC server; returns (server, bound port). Workers leave headroom for a reconnecting actor.

    Only calls carrying `token` reach a handler; each other call is answered UNAUTHENTICATED and passed to
    `on_refused(peer, method)`. A port in use is an AccrueError, not a shared port."""
    from concurrent import futures

    grpc = _grpc()
    parse_address(address, "learner listen address", allow_zero=True)
    if not token:
        raise AccrueError("learner link: no token to check callers against")
    if (tls_cert is None) != (tls_key is None):
        raise AccrueError("learner link: TLS needs both a certificate and its key")
    expected = token.encode()
    pair = tls_pair(Path(tls_cert), Path(tls_key)) if tls_cert is not None else None

    def wrap(name: str, fn: Handler):
        def call(request: bytes, context) -> bytes:
            given = dict(context.invocation_metadata()).get(METADATA_KEY, "")
            if not hmac.compare_digest(str(given).encode(), expected):
                if on_refused is not None:
                    try:
                        on_refused(context.peer(), name)
                    except Exception:  # noqa: BLE001 - recording a refusal must not let the call in
                        pass
                context.abort(grpc.StatusCode.UNAUTHENTICATED, "link token missing or wrong")
            try:
                header, blob = unpack(request)
                out, out_blob = fn(header, blob)
            except Exception as exc:  # noqa: BLE001 - a bad request must not kill the learner
                return pack({"error": f"{type(exc).__name__}: {exc}"})
            return pack(out, out_blob)

        return grpc.unary_unary_rpc_method_handler(call)

    server = grpc.server(futures.ThreadPoolExecutor(max_workers=workers), options=_SERVER_OPTIONS)
    server.add_generic_rpc_handlers(
        (grpc.method_handlers_generic_handler(SERVICE, {name: wrap(name, fn) for name, fn in handlers.items()}),)
    )
    try:
        if pair is not None:
            creds = grpc.ssl_server_credentials([pair])
            port = server.add_secure_port(address, creds)
        else:
            port = server.add_insecure_port(address)
    except RuntimeError:
        port = 0
    if port == 0:
        raise AccrueError(f"learner: cannot listen on {address!r} ({_why_not_listening(address)})")
    server.start()
    return server, port


def _why_not_listening(address: str) -> str:
    """Why gRPC could not bind `address`, found by binding it with a plain socket; for a port in use, a
    port that is free on that host now, to give as --listen (and to the actor as robot.learner_address)."""
    import errno
    import socket

    host, port = parse_address(address, "learner listen address", allow_zero=True)
    bare = host[1:-1] if host.startswith("[") else host
    try:
        family, kind, proto, _, sockaddr = socket.getaddrinfo(
            bare, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )[0]
    except socket.gaierror:
        return f"{host} is not a name or address of this machine"

    def bind(addr) -> int:
        with socket.socket(family, kind, proto) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as gRPC binds
            probe.bind(addr)
            probe.listen(1)  # with SO_REUSEADDR a bind alone succeeds on a port a connection holds
            return probe.getsockname()[1]

    try:
        bind(sockaddr)
    except OSError as exc:
        if exc.errno != errno.EADDRINUSE:
            return f"{host} is not an address of this machine ({exc.strerror}); 0.0.0.0 listens on all of them"
        free = None
        # the next free port above it (one to write in both workflows), else one the kernel picks
        for candidate in [*range(port + 1, min(port + 100, 65535) + 1), 0]:
            try:
                free = bind((sockaddr[0], candidate, *sockaddr[2:]))
                break
            except OSError:
                continue
        if free is None:
            return "the port is in use"
        return (
            f"the port is in use, by another learner or program; port {free} is free now: "
            f"--listen {host}:{free}, and robot.learner_address: <this host>:{free} in the actor's workflow"
        )
    return "gRPC refused the address; a plain socket could bind it, so try again"


_UNRESOLVED = re.compile(r"(?i)errors resolving|DNS resolution failed|lookup (?:error|failed)|Domain name not found")


def down_reason(address: str, code, details: str, timeout: float) -> str:
    """Why a call did not get through, as the operator fixes it: a name that does not resolve, nothing
    listening at the address, no answer in time; else gRPC's status and the start of its details."""
    host = address.rpartition(":")[0]
    if _UNRESOLVED.search(details):
        return f"the name {host} does not resolve (no such host; check robot.learner_address)"
    if "Connection refused" in details:
        return "nothing listens there (connection refused): is the learner running, on that port?"
    name = code.name if code is not None else "?"
    if name == "DEADLINE_EXCEEDED":
        return f"no answer within {timeout:g} s"
    short = details.strip().splitlines()[0][:160] if details.strip() else ""
    return f"{name} ({short})" if short else name


class Peer:
    """The actor's end of the link: `token` goes with every call; `tls_ca` (a PEM file) turns on TLS and
    is the certificate authority the learner's certificate must be signed by."""

    def __init__(self, address: str, token: str | None = None, tls_ca: Path | None = None):
        grpc = _grpc()
        self.address = address
        self._grpc = grpc
        self._metadata = ((METADATA_KEY, token),) if token else None
        if tls_ca is not None:
            ca = check_pem(tls_ca, "certificate", "robot.link.tls.ca")
            creds = grpc.ssl_channel_credentials(root_certificates=ca)
            self.channel = grpc.secure_channel(address, creds, options=_OPTIONS)
        else:
            self.channel = grpc.insecure_channel(address, options=_OPTIONS)

    def call(self, method: str, header: dict, blob: bytes = b"", timeout: float = 5.0) -> tuple[dict, bytes]:
        fn = self.channel.unary_unary(f"/{SERVICE}/{method}")
        try:
            data = fn(pack(header, blob), timeout=timeout, metadata=self._metadata)
        except self._grpc.RpcError as exc:
            code = exc.code() if hasattr(exc, "code") else None
            status = self._grpc.StatusCode
            if code in (status.UNAUTHENTICATED, status.PERMISSION_DENIED):
                raise LinkRefused(
                    f"{method} to {self.address}: {code.name} (the learner refused this actor's link token)"
                ) from None
            details = str(exc.details() if hasattr(exc, "details") else "") or ""
            if code == status.UNAVAILABLE and _TLS_FAILED.search(details):
                why = details.rpartition("OPENSSL_internal:")[2].removesuffix(": OK").strip()
                raise LinkRefused(f"{method} to {self.address}: TLS handshake failed ({why[:200]})", "tls") from None
            raise PeerDown(f"{method} to {self.address}: {down_reason(self.address, code, details, timeout)}") from None
        out, out_blob = unpack(data)
        if "error" in out:
            raise AccrueError(f"learner at {self.address} refused {method}: {out['error']}")
        return out, out_blob

    def close(self) -> None:
        self.channel.close()
