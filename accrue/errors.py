"""The one error type of the method layer: a user-facing problem with a one-line message."""


class AccrueError(Exception):
    """A problem the user can fix (bad task id, bad USD file, wrong dataset features, ...)."""
