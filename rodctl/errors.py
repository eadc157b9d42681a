"""Errors the user can fix. The CLI prints their message and exits with code 2, no traceback."""

import errno
from collections.abc import Iterable
from pathlib import Path


class UserError(Exception):
    """Bad input: a config, a file, an argument. `str(err)` is the whole user-facing message."""


class RunFailed(Exception):
    """A run that could not go on for a reason outside its input: a full disk, a read-only or
    vanished folder. The CLI prints the message and exits with code 1, no traceback."""


def pose_text(pose: Iterable[float]) -> str:
    """A pose (or any vector) in a message as a user writes it in YAML, to 4 decimals:
    `[0.4233, 0.2469, 0.0]`, not numpy's `np.float64(...)` reprs."""
    return str([round(float(v), 4) for v in pose])


def describe_os_error(exc: OSError) -> str:
    """One line saying what failed and where, e.g. "No space left on device: runs/x/run.mcap"."""
    what = exc.strerror or type(exc).__name__
    where = exc.filename if exc.filename is not None else ""
    return f"{what}: {where}" if where else f"{what} ({exc})"


#: OS errors that mean the `--out` path the user gave is wrong (a file in the way, a name too
#: long, a place no folder can be made, such as under /proc), not that the system refused:
#: exit 2. Every other (full disk, no inodes, read-only, permission, I/O) means the run could
#: not go on: exit 1 (docs/reliability.md, "The exit-code rule").
BAD_PATH_ERRNOS = frozenset(
    {errno.ENOTDIR, errno.EEXIST, errno.ENAMETOOLONG, errno.ELOOP, errno.EINVAL, errno.ENOENT}
)


def out_error(option: str, path: str | Path, what: str, exc: OSError) -> UserError | RunFailed:
    """The one-line error of an output path that cannot be used: `UserError` (exit 2) for a
    wrong path, `RunFailed` (exit 1) for a full, read-only or forbidden disk."""
    message = f"{option} {path}: {what}: {describe_os_error(exc)}"
    return UserError(message) if exc.errno in BAD_PATH_ERRNOS else RunFailed(message)


def out_path(path: str | Path, option: str = "--out") -> Path:
    """`path` as given for an output folder, checked without creating anything: so a command
    refuses it before its work, not after.

    Raises:
        UserError: an empty or blank path (which would silently mean the current folder), or
            a file where the folder or one of its parents would be.
    """
    if not str(path).strip():
        raise UserError(f"{option}: empty; give a folder's path (`.` is the current folder)")
    folder = Path(path)
    for place in (folder, *folder.parents):
        try:
            if not place.exists():
                continue
            is_dir = place.is_dir()
        except OSError as exc:  # a name too long (Python 3.11's exists() raises it), EACCES
            raise out_error(option, folder, "cannot use the output folder", exc) from None
        if not is_dir:
            raise UserError(f"{option} {folder}: {place} is a file, not a folder")
        break
    return folder


def make_out_folder(path: str | Path, option: str = "--out") -> Path:
    """Create the output folder `path` (and its parents) that a command writes into; the same
    rule and wording for every command's `--out`/`-o`.

    Raises:
        UserError: an empty path (it would silently mean the current folder), a file in the
            way, a name too long, a place no folder can be made.
        RunFailed: the system refused: a full, read-only or forbidden disk.
    """
    folder = out_path(path, option)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise out_error(option, folder, "cannot create the output folder", exc) from None
    return folder
