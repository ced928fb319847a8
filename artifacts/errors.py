"""Errors of the artifact store: each carries a one-line, user-facing message."""

from __future__ import annotations

import reprlib

QUOTE_LIMIT = 200  # characters of user input a message may quote


class StoreError(Exception):
    """A store problem the user must know about (missing or corrupt object, bad ref, lock held)."""


def quote(value: object, limit: int = QUOTE_LIMIT) -> str:
    """repr() of user input for a message, bounded in time, memory and length: a YAML alias bomb
    or a huge file must not become a 300 MB error line."""
    short = reprlib.Repr()
    short.maxstring = short.maxother = limit
    short.maxlevel = 3
    short.maxlist = short.maxtuple = short.maxdict = short.maxset = 8
    text = short.repr(value)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def os_error_text(exc: OSError) -> str:
    """'<path>: <reason>' for an OSError, with the path shortened and escaped."""
    why = exc.strerror or str(exc) or exc.__class__.__name__
    names = [n for n in (exc.filename, exc.filename2) if n is not None]
    if not names:
        return why
    where = " -> ".join(path_text(n) for n in names)
    return f"{where}: {why}"


def path_text(name: object) -> str:
    text = name.decode("utf-8", "backslashreplace") if isinstance(name, bytes) else str(name)
    text = text.encode("utf-8", "backslashreplace").decode("utf-8")  # undecodable bytes of a file name
    return text if len(text) <= QUOTE_LIMIT else "…" + text[-(QUOTE_LIMIT - 1) :]


def store_os_error(exc: OSError, what: str) -> StoreError:
    """A StoreError for an OSError met while doing `what` (e.g. "writing to the store at X")."""
    return StoreError(f"{what}: {os_error_text(exc)}")
