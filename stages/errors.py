"""Errors of the runner and workflows: each carries a one-line, user-facing message."""


class StageError(Exception):
    """A workflow or step problem (bad workflow field, refused input, step already running)."""
