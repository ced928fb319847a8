"""`accrue robot learner`: the learner process of a hardware stage on another host (the GPU box), and
`accrue robot certs`: a self-signed TLS pair for that link on a lab LAN, and `accrue robot token`: the store's
link token made (if new) and copied for the learner's host.

The actor (`accrue stage run` beside the robot, with `robot.learner_address: HOST:PORT`) sends it what it
needs and every sealed episode; this process holds nothing durable and may be restarted at any time.
Every call must carry the store's link token (docs/ROBOT_LINK.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from cli.store_cmds import StoreOpt

robot_app = typer.Typer(
    help="Robot sessions: check a robot workflow, the learner process for a second host, its token and TLS.",
    no_args_is_help=True,
)

CERT_FILE, KEY_FILE = "learner.crt", "learner.key"


def store_audit(store_dir: Path):
    """audit(event, fields) appending to the store's audit log (refused link calls)."""
    from artifacts.auditlog import append_event
    from artifacts.store import Store

    store = Store.open(store_dir)

    def audit(event: str, fields: dict) -> None:
        append_event(store, event, **fields)

    return audit


@robot_app.command("learner")
def learner(
    listen: Annotated[
        str, typer.Option("--listen", help="HOST:PORT to serve the actor on (another host: needs TLS).")
    ] = "127.0.0.1:50051",
    store: Annotated[
        Optional[Path],
        typer.Option("--store", help="The actor's store (shared filesystem): its link token and audit log."),
    ] = None,
    token_file: Annotated[
        Optional[Path], typer.Option("--token-file", help="A copy of the store's robot/link-token (mode 0600).")
    ] = None,
    tls_cert: Annotated[
        Optional[Path], typer.Option("--tls-cert", help="PEM certificate (accrue robot certs).")
    ] = None,
    tls_key: Annotated[Optional[Path], typer.Option("--tls-key", help="PEM private key of --tls-cert.")] = None,
    insecure: Annotated[
        bool, typer.Option("--insecure", help="Allow a non-loopback address without TLS (a trusted LAN only).")
    ] = False,
    tracking: Annotated[
        Optional[Path],
        typer.Option(
            "--tracking-dir",
            help="Where to write the learner's scalars (default: the store's log/tracking with --store, else none).",
        ),
    ] = None,
) -> None:
    """Serve an actor's learner over gRPC until interrupted; only callers with the link token get in."""
    from accrue.errors import AccrueError
    from accrue.robot.learner_service import check_listen, main

    argv = ["--listen", listen]
    for flag, value in (("--tls-cert", tls_cert), ("--tls-key", tls_key)):
        if value is not None:
            argv += [flag, str(value)]
    if insecure:
        argv.append("--insecure")
    if tracking is not None:
        argv += ["--tracking-dir", str(tracking)]
    # the address first: a mistake there is one line before anything touches the store
    check_listen(listen, tls_cert is not None, insecure, prog="accrue robot learner")
    audit = None
    if store is not None:
        from accrue.robot.link_auth import TOKEN_ENV, store_token

        if token_file is not None:
            raise AccrueError("accrue robot learner: give --store or --token-file, not both")
        import os

        audit = store_audit(store)
        os.environ[TOKEN_ENV] = store_token(store)  # the learner pops it: not in argv, not inherited
        if tracking is None:  # the store's log/tracking, where the actor's runs are
            from accrue.tracking import tracking_dir

            argv += ["--tracking-dir", str(tracking_dir(store, "").absolute())]
    elif token_file is not None:
        argv += ["--token-file", str(token_file)]
    raise typer.Exit(main(argv, audit=audit))


@robot_app.command("token")
def token(
    store: StoreOpt = None,
    out: Annotated[
        Optional[Path], typer.Option("--out", help="Also write a copy here (mode 0600), for the learner's host.")
    ] = None,
    show: Annotated[bool, typer.Option("--show", help="Print the token itself (it is a secret).")] = False,
) -> None:
    """Make the store's link token if it has none yet, and say where it is (never the token, unless --show).

    The learner (--store or --token-file) and the actor (robot.learner_address) use this same token."""
    import os
    import secrets

    from accrue.errors import AccrueError
    from accrue.robot.link_auth import TOKEN_FILE, read_token_file, store_token
    from cli.store_cmds import open_store

    root = open_store(store).root
    existed = (root / TOKEN_FILE).is_file()
    value = store_token(root)
    print(f"link token: {root / TOKEN_FILE} (0600{', made now' if not existed else ''})")
    if out is not None:
        out = out.expanduser()
        if out.exists():
            try:
                same = out.is_file() and out.read_text().strip() == value
            except (OSError, UnicodeDecodeError):
                same = False
            if not same:
                raise AccrueError(f"accrue robot token: {out} exists and is not this token; remove it first")
            read_token_file(out, "accrue robot token --out")  # the copy is private (0600), or one line
        else:
            tmp = out.with_name(f".{out.name}.{os.getpid()}.{secrets.token_hex(4)}")
            try:
                fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            except OSError as exc:
                raise AccrueError(f"accrue robot token: cannot write {out} ({exc.strerror})") from None
            try:
                os.write(fd, (value + "\n").encode())
                os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, out)
        print(f"copied to {out} (0600): give it to the learner as --token-file, or as robot.link.token_file")
    if show:
        print(value)


@robot_app.command("certs")
def certs(
    directory: Annotated[Path, typer.Argument(help="Where to write learner.crt and learner.key.")],
    host: Annotated[
        Optional[list[str]],
        typer.Option("--host", help="Name or IP the actor dials (repeatable; default: this machine's name)."),
    ] = None,
    days: Annotated[int, typer.Option("--days", min=1, help="Validity.")] = 825,
) -> None:
    """Make a self-signed certificate and key for the learner link on a lab LAN.

    The learner uses both (--tls-cert/--tls-key); the actor trusts the certificate (robot.link.tls.ca)."""
    import datetime
    import ipaddress
    import os
    import socket

    from accrue.errors import AccrueError

    try:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import NameOID
    except ImportError:
        raise AccrueError(
            "accrue robot certs needs the `cryptography` package; or make a pair with openssl (docs/ROBOT_LINK.md)"
        ) from None
    for name in host or []:  # an empty name would be a certificate no actor can dial
        if not name.strip() or any(c.isspace() or c in "/\\" for c in name):
            raise AccrueError(f"accrue robot certs --host: {name!r} is not a host name or IP address")
    names = list(dict.fromkeys([*(host or [socket.gethostname()]), "localhost", "127.0.0.1"]))
    directory = Path(directory)
    cert_path, key_path = directory / CERT_FILE, directory / KEY_FILE
    for p in (cert_path, key_path):
        if p.exists():
            raise AccrueError(f"accrue robot certs: {p} exists; remove it or choose another directory")
    sans: list[x509.GeneralName] = []
    for name in names:
        try:
            sans.append(x509.IPAddress(ipaddress.ip_address(name)))
        except ValueError:
            sans.append(x509.DNSName(name))
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"accrue learner {names[0]}")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(x509.SubjectAlternativeName(sans), critical=False)
        # its own CA: the actor trusts exactly this certificate
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .sign(key, hashes.SHA256())
    )
    directory.mkdir(parents=True, exist_ok=True)
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(
            key.private_bytes(
                serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
            )
        )
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    print(f"wrote {cert_path} and {key_path} (0600) for {', '.join(names)}, valid {days} days")
    print(
        f"learner: accrue robot learner --listen 0.0.0.0:50051 --tls-cert {cert_path} --tls-key {key_path} ...; "
        f"actor: robot.link.tls.ca: {cert_path} (copy the .crt only)"
    )


@robot_app.command("check")
def check(
    workflow: Annotated[Path, typer.Argument(metavar="WORKFLOW", help="Workflow YAML file with a robot: section.")],
    task: Annotated[
        Optional[str], typer.Option("--task", help="The task whose robot to connect (default: the first).")
    ] = None,
    store: StoreOpt = None,
) -> None:
    """Check a robot workflow against the robot, moving nothing: every check `accrue run` makes before a step,
    then connect the robot, read one observation, check it against the workflow's bounds, disconnect.

    No action is ever sent. With robot.learner_address, the learner is asked Hello with the link token."""
    from accrue.errors import AccrueError
    from cli.store_cmds import open_store
    from stages.errors import StageError
    from stages.steps.robot_preflight import observe_once, preflight, reach_learner
    from stages.workflow import load_workflow

    wf = load_workflow(workflow)
    if wf.robot is None:
        raise StageError(f"{workflow}: no robot: section (accrue robot check is for robot workflows)")
    if task is not None and task not in wf.tasks:
        raise StageError(f"--task: {task!r} is not one of the workflow's tasks ({', '.join(wf.tasks)})")
    st = open_store(store)
    checked = preflight(wf, str(workflow), st)
    robot = next(rc for rc in checked.robots if rc.task == (task or wf.tasks[0]))
    m = robot.mapping
    print(
        f"workflow {wf.name}: robot.type {wf.robot.type} ({robot.config_class}), its config, keys and cameras "
        f"fit the workflow and base_policy.init for {len(checked.robots)} task(s)"
    )
    try:
        seen = observe_once(wf, robot)
        learner = reach_learner(wf, st) if wf.robot.learner_address is not None else None
    except AccrueError as exc:
        raise StageError(f"{workflow}: {exc}") from None
    print(f"task {robot.task}: connected in {seen.connect_s:.1f} s, read one observation, sent no action")
    print(f"q ({len(seen.state)}): " + ", ".join(f"{k}={v:.4g}" for k, v in seen.state.items()))
    print(f"actions ({m.action_mode}): {', '.join(m.action_keys)}")
    cams = ", ".join(f"{k} {list(shape)}" for k, shape in seen.cameras.items())
    print(f"cameras: {cams or 'none'}")
    print(learner or "learner: started by the actor on this host (no robot.learner_address)")
    if seen.findings:
        for line in seen.findings:
            print(f"out of bounds: {line}")
        raise StageError(
            f"{workflow}: the robot's observation is outside the workflow's bounds ({len(seen.findings)} finding"
            f"{'s' if len(seen.findings) > 1 else ''} above): fix the robot's pose or the bounds before a run"
        )
    print("within bounds: robot.safety" + (", robot.action_bounds" if m.action_mode == "joint" else ""))


def register(app: typer.Typer) -> None:
    app.add_typer(robot_app, name="robot")
