"""Errors the user can fix. The CLI prints their message and exits with code 2, no traceback."""


class UserError(Exception):
    """Bad input: a config, a file, an argument. `str(err)` is the whole user-facing message."""


class RunFailed(Exception):
    """A run that could not go on for a reason outside its input: a full disk, a read-only or
    vanished folder. The CLI prints the message and exits with code 1, no traceback."""


def describe_os_error(exc: OSError) -> str:
    """One line saying what failed and where, e.g. "No space left on device: runs/x/run.mcap"."""
    what = exc.strerror or type(exc).__name__
    where = exc.filename if exc.filename is not None else ""
    return f"{what}: {where}" if where else f"{what} ({exc})"
