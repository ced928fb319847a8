"""Errors of the artifact store: each carries a one-line, user-facing message."""


class StoreError(Exception):
    """A store problem the user must know about (missing or corrupt object, bad ref, lock held)."""
