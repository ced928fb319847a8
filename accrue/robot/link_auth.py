"""Who may drive the actor-learner link: the learner's address, the link token and the TLS files.

Every call on the link carries a token (gRPC metadata `accrue-link-token`); the learner refuses any call
without it, before the call's handler runs. The token is per store (`<store>/robot/link-token`, mode 0600,
made on first use) or a file the operator gives (`robot.link.token_file`), and it is never printed, logged
or put on a command line: a learner the actor starts itself gets it in an inherited environment variable.
TLS (`robot.link.tls`) is for a learner on another host; docs/ROBOT_LINK.md describes the whole link.
"""

from __future__ import annotations

import ipaddress
import os
import re
import secrets
import stat
from dataclasses import dataclass, field
from pathlib import Path

from accrue.errors import AccrueError

TOKEN_FILE = Path("robot") / "link-token"
TOKEN_ENV = "ACCRUE_LINK_TOKEN"  # how a spawned learner receives its token (never argv)
METADATA_KEY = "accrue-link-token"
LINK_KEYS = {"token_file", "tls"}
TLS_KEYS = {"cert", "key", "ca"}


def parse_address(text: str, where: str, *, allow_zero: bool = False) -> tuple[str, int]:
    """HOST:PORT -> (host, port); anything else is one AccrueError line naming `where` and the text."""
    low = 0 if allow_zero else 1
    bad = AccrueError(f"{where}: {text!r} is not HOST:PORT with a port in {low}..65535")
    if not isinstance(text, str):
        raise bad
    host, sep, port = text.strip().rpartition(":")
    # re, not str.isdigit: "-5", "+5" and non-ASCII digits are not ports
    if not sep or not host or not re.fullmatch(r"[0-9]{1,5}", port) or not low <= int(port) <= 65535:
        raise bad
    bare = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not bare or any(c.isspace() for c in bare) or (":" in bare and bare == host):
        raise bad  # an IPv6 host needs its brackets: [::1]:50051
    return host, int(port)


def is_loopback(host: str) -> bool:
    bare = host[1:-1] if host.startswith("[") else host
    if bare == "localhost":
        return True
    try:
        return ipaddress.ip_address(bare).is_loopback
    except ValueError:
        return False


def _read_token(path: Path, where: str) -> str:
    try:
        mode = path.stat().st_mode
        text = path.read_text().strip()
    except OSError as exc:
        raise AccrueError(f"{where}: cannot read the link token file {path} ({exc.strerror})") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise AccrueError(f"{where}: the link token file {path} is readable by others (chmod 600 {path})")
    if not text:
        raise AccrueError(f"{where}: the link token file {path} is empty")
    return text


def read_token_file(path: Path | str, where: str = "link token") -> str:
    return _read_token(Path(path).expanduser(), where)


def store_token(store_root: Path) -> str:
    """The store's link token, made once (0600) and read afterwards; never printed or logged."""
    path = Path(store_root) / TOKEN_FILE
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".link-token.{os.getpid()}.{secrets.token_hex(4)}")
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        try:
            os.write(fd, (secrets.token_urlsafe(32) + "\n").encode())
            os.fsync(fd)
        finally:
            os.close(fd)
        try:
            os.link(tmp, path)  # atomic and never replaces: two first uses agree on one token
        except FileExistsError:
            pass
        finally:
            tmp.unlink()
    return _read_token(path, f"store {store_root}")


_PEM_BLOCK = re.compile(r"-----BEGIN ([A-Z0-9 ]+)-----\s*([A-Za-z0-9+/=\s]+?)-----END \1-----")


def pem_labels(data: bytes) -> list[str]:
    """The labels of the well-formed PEM blocks in `data` ("CERTIFICATE", "PRIVATE KEY", ...), in order."""
    import base64
    import binascii

    text = data.decode("ascii", errors="replace")
    labels = []
    for m in _PEM_BLOCK.finditer(text):
        try:
            if base64.b64decode("".join(m.group(2).split()), validate=True):
                labels.append(m.group(1))
        except (binascii.Error, ValueError):
            continue
    return labels


def check_pem(path: Path | str, kind: str, where: str) -> bytes:
    """The bytes of a PEM file holding a certificate (`kind` "certificate") or a private key ("key");
    anything else - unreadable, not PEM, the other kind - is one AccrueError line naming `where` and the file."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise AccrueError(f"{where}: cannot read {path} ({exc.strerror})") from None
    labels = pem_labels(data)
    wanted = "CERTIFICATE" if kind == "certificate" else "PRIVATE KEY"
    if not any(label == wanted or (kind == "key" and label.endswith(" PRIVATE KEY")) for label in labels):
        found = f"it holds {', '.join(sorted(set(labels)))}" if labels else "it is not PEM"
        raise AccrueError(f"{where}: {path} is not a PEM {kind} ({found}; -----BEGIN {wanted}----- expected)")
    return data


@dataclass(frozen=True)
class LinkAuth:
    token: str = field(repr=False)
    tls_cert: Path | None = None
    tls_key: Path | None = None
    tls_ca: Path | None = None
    token_from: Path | None = None  # the file the token was read from (named in a refusal, never the token)

    @classmethod
    def ephemeral(cls) -> "LinkAuth":
        """A token for one actor and the learner it starts itself (nobody else ever sees it)."""
        return cls(secrets.token_urlsafe(32))


def validate_link_section(d: dict | None, where: str) -> dict:
    """robot.link: {token_file: F, tls: {cert, key, ca}}, every file present (the TLS ones PEM of their
    kind); paths made absolute."""
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise AccrueError(f"{where}: expected a mapping with keys {sorted(LINK_KEYS)}, got {d!r}")
    unknown = sorted(set(d) - LINK_KEYS)
    if unknown:
        raise AccrueError(f"{where}: unknown key(s) {unknown}; known: {sorted(LINK_KEYS)}")
    out: dict = {}

    def file(value, key: str) -> str:
        if not isinstance(value, (str, os.PathLike)) or not str(value):
            raise AccrueError(f"{where}.{key}: expected a file path, got {value!r}")
        path = Path(value).expanduser().absolute()
        if not path.is_file():
            raise AccrueError(f"{where}.{key}: no such file {path}")
        return str(path)

    if d.get("token_file") is not None:
        out["token_file"] = file(d["token_file"], "token_file")
    tls = d.get("tls")
    if tls is not None:
        if not isinstance(tls, dict):
            raise AccrueError(f"{where}.tls: expected a mapping with keys {sorted(TLS_KEYS)}, got {tls!r}")
        unknown = sorted(set(tls) - TLS_KEYS)
        if unknown:
            raise AccrueError(f"{where}.tls: unknown key(s) {unknown}; known: {sorted(TLS_KEYS)}")
        out["tls"] = {k: file(v, f"tls.{k}") for k, v in tls.items() if v is not None}
        for k, path in out["tls"].items():  # a wrong file is found here, not as a learner that never answers
            check_pem(path, "key" if k == "key" else "certificate", f"{where}.tls.{k}")
    return out


def link_auth_for(robot_section: dict, store_root: Path) -> LinkAuth:
    link = validate_link_section((robot_section or {}).get("link"), "robot.link")
    token = read_token_file(link["token_file"], "robot.link.token_file") if "token_file" in link else None
    tls = {k: Path(v) for k, v in link.get("tls", {}).items()}
    source = Path(link["token_file"]) if token else Path(store_root).absolute() / TOKEN_FILE
    return LinkAuth(
        token or store_token(store_root),
        tls_cert=tls.get("cert"),
        tls_key=tls.get("key"),
        tls_ca=tls.get("ca"),
        token_from=source,
    )
