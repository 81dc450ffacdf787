"""Where fgcal writes, and how: the one place that enforces it (docs/formats.md, "What fgcal
reads and writes").

A command writes only into the folder or file its command line names (``--out``, ``--urdf``,
``--state``), creating the folder and its parents. Inside it, nothing is written through a
symbolic link, to a file or to a folder: a link left where an output goes (by another tool, or
planted) would carry the write out of the folder. A folder the command line names may itself
be a link (the user named it).
"""

from __future__ import annotations

import errno
import io
import os
from pathlib import Path

from .errors import InputError


def output_dir(path: str | Path, field: str | None = "--out") -> Path:
    """The folder ``path`` (named on the command line), created with its parents; an error when
    it is a file."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(path, field, "is a file: name a folder to write into")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(path, field, f"cannot create the folder: {exc.strerror}") from None
    return path


def subfolder(parent: Path, name: str) -> Path:
    """A folder inside an output folder, created; never a link."""
    path = Path(parent) / name
    if path.is_symlink():
        raise InputError(path, None, "is a symbolic link: fgcal does not write through links")
    if path.exists() and not path.is_dir():
        raise InputError(path, None, "is a file where fgcal writes a folder")
    path.mkdir(exist_ok=True)
    return path


def output_file(path: str | Path, field: str | None = None) -> Path:
    """A file a command writes, checked before a writer it does not control (savefig,
    cv2.imwrite) opens it: not a link, not a folder, and its folder there."""
    path = Path(path)
    if path.is_symlink():
        raise InputError(path, field, "is a symbolic link: fgcal does not write through links")
    if path.is_dir():
        raise InputError(path, field, "is a folder: name the file to write")
    if path.exists() and not path.is_file():  # a FIFO would block the writer, a device swallow the output
        raise InputError(path, field, "is not a regular file (a FIFO, a device or a socket): name a file to write")
    if not path.parent.is_dir():
        raise InputError(path, field, f"no such folder {path.parent}")
    return path


def _identity(path: str | Path) -> tuple:
    """What makes two names one file: an existing file's device and inode (so that a hard link
    or a symbolic link to a file is that file), else its absolute path with links resolved (an
    output not yet written is no input, but two outputs may still be one name)."""
    try:
        status = os.stat(path)
    except (OSError, ValueError):
        try:
            return ("path", Path(path).resolve())
        except (OSError, RuntimeError):  # a loop of links: compared as named
            return ("path", Path(path).absolute())
    return ("file", status.st_dev, status.st_ino)


def distinct(outputs: dict[str, str | Path | None], inputs: dict[str, str | Path | None]) -> None:
    """Refuse an output that is one of the command's inputs or another output: the same file
    (device and inode, through symbolic and hard links), not merely the same name. Writing it
    would destroy what the command reads, or write one file twice."""
    seen: dict[tuple, tuple[str, str | Path]] = {}
    for role, path in inputs.items():  # inputs may be one file (a robot its own nominal model)
        if path is not None:
            seen.setdefault(_identity(path), (f"input {role}", path))
    for role, path in outputs.items():
        if path is None:
            continue
        key = _identity(path)
        if key in seen:
            other, named = seen[key]
            link = "" if Path(named).absolute() == Path(path).absolute() else f" ({named}, through a link)"
            raise InputError(path, role, f"is the same file as {other}{link}: name another output")
        seen.setdefault(key, (role, path))


def write_bytes(path: str | Path, data: bytes, field: str | None = None, sync: bool = False) -> Path:
    """Write a file, never through a symbolic link (O_NOFOLLOW) and never over a folder;
    ``sync``: on the disk before returning (a file another process takes)."""
    path = output_file(path, field)
    try:
        descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW, 0o644)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(path, field, "is a symbolic link: fgcal does not write through links") from None
        raise InputError(path, field, f"cannot write: {exc.strerror}") from None
    with os.fdopen(descriptor, "wb") as handle:
        handle.write(data)
        if sync:
            handle.flush()
            os.fsync(handle.fileno())
    return path


def write_text(path: str | Path, text: str, field: str | None = None, sync: bool = False) -> Path:
    return write_bytes(path, text.encode("utf-8"), field, sync)


def save_figure(figure, path: str | Path, **options) -> Path:
    """A matplotlib figure saved as PNG through write_bytes."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", **options)
    return write_bytes(path, buffer.getvalue())
