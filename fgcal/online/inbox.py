"""What ``fgcal online`` takes from its inbox, and how (docs/online.md, "Inbox protocol").

- Only regular files named ``*.json`` (not hidden) are measurements. A symbolic link (which
  could point anywhere outside the inbox), a FIFO (reading it would block), a device, a socket
  or a folder so named is refused: moved to ``STATE/rejected/`` with the reason. So is a name
  that is not UTF-8 text of at most MAX_NAME characters without control characters, stored
  there under a safe name (``odd-name-<hash>.json``) with the original in the reason.
- A measurement is *claimed* before it is read: renamed, atomically, to a hidden name that
  carries this process's id (``.NAME.PID.claim``). Two services sharing an inbox each take
  their own files; a file another process claimed first is simply gone. A claim left by a
  process that died is taken back at start.
- A claimed file is opened without following links and without blocking, and read only if it
  is a regular file.
"""

from __future__ import annotations

import hashlib
import os
import stat
import unicodedata
from dataclasses import dataclass
from pathlib import Path

MAX_NAME = 120  # characters of a measurement file's name
CLAIM = ".claim"


@dataclass(frozen=True)
class Entry:
    path: Path  # where it is in the inbox
    name: str  # its name (the measurement's identity)
    problem: str | None  # why it is refused, or None


def odd_name(name: str) -> bool:
    """Not UTF-8 (undecodable bytes come back as surrogates), too long, or with control characters."""
    if len(name) > MAX_NAME:
        return True
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return True
    return any(unicodedata.category(c) == "Cc" for c in name)


def safe_name(name: str) -> str:
    """The name as it is when fine; else a name made from its bytes' hash."""
    if not odd_name(name):
        return name
    return f"odd-name-{hashlib.sha1(os.fsencode(name)).hexdigest()[:16]}.json"


def entries(inbox: Path) -> list[Entry]:
    """The inbox's measurement candidates in name order, with what is wrong with each."""
    out = []
    try:
        scanned = list(os.scandir(inbox))
    except OSError:
        return []
    for item in scanned:
        name = item.name
        if name.startswith(".") or not name.endswith(".json"):
            continue
        problem = None
        if odd_name(name):
            problem = f"its name {name!r} is not UTF-8 text of at most {MAX_NAME} characters without control characters"
        elif item.is_symlink():
            problem = "a symbolic link: only regular files are read from the inbox"
        elif not item.is_file(follow_symlinks=False):
            problem = "not a regular file (a FIFO, a device, a socket or a folder): only regular files are read"
        out.append(Entry(Path(item.path), name, problem))
    return sorted(out, key=lambda e: os.fsencode(e.name))


def claim(inbox: Path, entry: Entry) -> Path | None:
    """The entry renamed to this process's claim; None when another process took it first."""
    claimed = inbox / f".{entry.name}.{os.getpid()}{CLAIM}"
    try:
        os.rename(entry.path, claimed)
    except FileNotFoundError:
        return None
    return claimed


def recover_claims(inbox: Path) -> list[str]:
    """Claims of processes no longer alive (or of this one) put back under their names; the
    names recovered."""
    recovered = []
    for item in os.scandir(inbox):
        if not (item.name.startswith(".") and item.name.endswith(CLAIM)):
            continue
        stem, _, pid = item.name[1 : -len(CLAIM)].rpartition(".")
        if not stem or not pid.isdigit() or (int(pid) != os.getpid() and _alive(int(pid))):
            continue
        target = inbox / stem
        if target.exists() or target.is_symlink():
            continue
        try:
            os.rename(item.path, target)
        except FileNotFoundError:
            continue
        recovered.append(stem)
    return recovered


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def read_regular(path: Path, limit: int) -> bytes:
    """The bytes of a regular file, opened without following a link or blocking on a FIFO;
    OSError (ELOOP, or ``not a regular file``, or too large) otherwise."""
    descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    try:
        info = os.fstat(descriptor)
        if not stat.S_ISREG(info.st_mode):
            raise OSError("not a regular file")
        if info.st_size > limit:
            raise OSError(f"larger than {limit} bytes: not a measurement file")
        chunks, total = [], 0
        while True:
            chunk = os.read(descriptor, 1 << 16)
            if not chunk:
                break
            total += len(chunk)
            if total > limit:
                raise OSError(f"larger than {limit} bytes: not a measurement file")
            chunks.append(chunk)
        return b"".join(chunks)
    finally:
        os.close(descriptor)
