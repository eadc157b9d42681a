"""Errors the user can fix. The CLI prints their message and exits with code 2, no traceback."""


class UserError(Exception):
    """Bad input: a config, a file, an argument. `str(err)` is the whole user-facing message."""
