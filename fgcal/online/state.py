"""The online state directory: what survives a crash.

- ``lock``: held (``fcntl.flock``) by the one process working on the directory; a second
  process is refused with the holder's pid.
- ``measurements.log``: append-only, one record per line, ``<crc32 hex> <json>\\n``. A
  measurement is *acknowledged* once its record is written and fsync'ed; only then is its
  inbox file moved aside. Reading the log checks every record: a truncated or corrupted
  last record (a crash during the append) is reported, skipped and cut off, so that later
  appends start clean (the service recovers it from processed/ when its file is there: it
  was acknowledged); a corrupted earlier record is reported and skipped.
- ``checkpoint.json``: every few images, written atomically (temporary file, fsync, rename):
  the number of records and the estimate at that point. A restart replays the log (the
  estimate is a deterministic function of it) and checks that the replay reproduces the
  checkpoint; a checkpoint that is not valid is reported and rebuilt from the log.
- A complete record that fails its check (damaged on disk) is recovered from its
  measurement file in ``processed/``, or else quarantined (``quarantine/``) with a message;
  the log is then rewritten without the damage.
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path

from ..core.errors import InputError

LOG = "measurements.log"
CHECKPOINT = "checkpoint.json"


@dataclass
class LogContents:
    records: list[dict]
    problems: list[str] = field(default_factory=list)
    # Complete records that failed their check: (valid records before it, the raw line).
    damaged: list[tuple[int, bytes]] = field(default_factory=list)
    # A truncated last record's bytes (a crash while writing it, or damage on disk): recovered
    # from its measurement file in processed/ when the measurement was acknowledged; None: none.
    truncated: bytes | None = None


def encode_record(record: dict) -> bytes:
    payload = json.dumps(record, separators=(",", ":"), sort_keys=True).encode("utf-8")
    return b"%08x " % zlib.crc32(payload) + payload + b"\n"


def decode_line(line: bytes) -> dict | None:
    """The record of a complete line, or None if it is corrupted."""
    if len(line) < 10 or line[8:9] != b" ":
        return None
    payload = line[9:]
    try:
        if int(line[:8], 16) != zlib.crc32(payload):
            return None
        record = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return None
    return record if isinstance(record, dict) else None


def checkpoint_problem(data: object, released: list[str]) -> str | None:
    """What is wrong with a checkpoint's content, or None."""
    if not isinstance(data, dict):
        return "not a JSON object"
    for key in ("n_records", "n_images"):
        if isinstance(data.get(key), bool) or not isinstance(data.get(key), int) or data[key] < 0:
            return f"{key} is not a count ({data.get(key)!r})"
    for key in ("estimate", "sigma"):
        values = data.get(key)
        if not isinstance(values, dict):
            return f"{key} is not a mapping of the released parameters"
        for name in released:
            value = values.get(name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                return f"{key}.{name} is missing or not a finite number ({value!r})"
    return None


# The state directory's own files: each must be a regular file, never a link or a folder.
FILES = (
    "lock",
    LOG,
    CHECKPOINT,
    "config.yaml",
    "report.json",
    "report.md",
    "calibrated_robot.yaml",
    "history.csv",
    "sigmas.png",
)


def _open_flags(flags: int) -> int:
    return flags | os.O_NOFOLLOW  # a link planted where a state file goes is never followed


def open_for_writing(path: Path, append: bool = False, binary: bool = False):
    """A state file opened for writing (truncated, or appended to), never through a link."""
    flags = os.O_WRONLY | os.O_CREAT | (os.O_APPEND if append else os.O_TRUNC)
    descriptor = os.open(path, _open_flags(flags), 0o644)
    return os.fdopen(descriptor, "ab" if binary else "w", **({} if binary else {"encoding": "utf-8"}))


def write_atomic(path: Path, data: bytes) -> None:
    temporary = path.with_name(f".{path.name}.tmp")
    if temporary.is_symlink():
        temporary.unlink()
    with open_for_writing(temporary, binary=True) as handle:
        handle.write(data)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(temporary, path)
    _fsync_directory(path.parent)


def _fsync_directory(directory: Path) -> None:
    descriptor = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


class StateDir:
    """Lock, log and checkpoint of one online calibration (see the module docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise InputError(self.path, "--state", "is a file: the state is a folder")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise InputError(self.path, "--state", f"cannot create the folder: {error.strerror}") from None
        for name in FILES:
            entry = self.path / name
            if entry.is_symlink() or (entry.exists() and not entry.is_file()):
                kind = "a symbolic link" if entry.is_symlink() else "a folder or a special file"
                raise InputError(entry, None, f"is {kind} where fgcal keeps its state file: move it away")
        self._lock_handle = None
        self._log_handle = None

    # -- lock -------------------------------------------------------------------------------

    def lock(self) -> None:
        descriptor = os.open(self.path / "lock", _open_flags(os.O_RDWR | os.O_CREAT), 0o644)
        handle = os.fdopen(descriptor, "a+")
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "unknown"
            handle.close()
            raise InputError(self.path, None, f"state directory is in use by another process (pid {holder})") from None
        handle.seek(0)
        handle.truncate()
        handle.write(str(os.getpid()))
        handle.flush()
        self._lock_handle = handle

    def close(self) -> None:
        if self._log_handle is not None:
            self._log_handle.close()
            self._log_handle = None
        if self._lock_handle is not None:
            fcntl.flock(self._lock_handle, fcntl.LOCK_UN)
            self._lock_handle.close()
            self._lock_handle = None

    def __enter__(self) -> StateDir:
        self.lock()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- log --------------------------------------------------------------------------------

    def read_log(self) -> LogContents:
        """Every valid record, in order; problems are described, and a damaged tail is cut
        off the file (only under the lock)."""
        path = self.path / LOG
        if not path.exists():
            return LogContents([])
        data = path.read_bytes()
        contents = LogContents([])
        position, good_end = 0, 0
        number = 0
        while position < len(data):
            newline = data.find(b"\n", position)
            number += 1
            if newline < 0:
                size = len(data) - position
                contents.problems.append(
                    f"{path}: record {number} is truncated ({size} bytes, a crash while writing): skipped"
                )
                contents.truncated = data[position:]
                break
            record = decode_line(data[position:newline])
            if record is None:
                contents.problems.append(f"{path}: record {number} is corrupted (checksum or JSON)")
                contents.damaged.append((len(contents.records), data[position:newline]))
            else:
                contents.records.append(record)
            position = newline + 1
            good_end = position
        if good_end < len(data) and self._lock_handle is not None:
            with open(path, "r+b") as handle:
                handle.truncate(good_end)
                handle.flush()
                os.fsync(handle.fileno())
        return contents

    def rewrite_log(self, records: list[dict]) -> None:
        """Replace the log by these records, atomically (a repaired log)."""
        if self._lock_handle is None:
            raise RuntimeError("rewrite_log needs the state directory's lock")
        if self._log_handle is not None:
            self._log_handle.close()
            self._log_handle = None
        write_atomic(self.path / LOG, b"".join(encode_record(r) for r in records))

    def append(self, record: dict) -> None:
        """Append one record and make it durable: after this returns, it is acknowledged."""
        if self._lock_handle is None:
            raise RuntimeError("append needs the state directory's lock")
        if self._log_handle is None:
            self._log_handle = open_for_writing(self.path / LOG, append=True, binary=True)
        self._log_handle.write(encode_record(record))
        self._log_handle.flush()
        os.fsync(self._log_handle.fileno())

    # -- checkpoint -------------------------------------------------------------------------

    def read_checkpoint(self, released: list[str]) -> tuple[dict | None, str | None]:
        """The checkpoint, checked against the released parameters, or (None, why it is not
        usable); no file is (None, None)."""
        path = self.path / CHECKPOINT
        if not path.exists():
            return None, None
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError, UnicodeDecodeError) as error:
            return None, f"{path} is not readable JSON ({error})"
        problem = checkpoint_problem(data, released)
        return (None, f"{path}: {problem}") if problem else (data, None)

    def write_checkpoint(self, checkpoint: dict) -> None:
        write_atomic(self.path / CHECKPOINT, json.dumps(checkpoint, indent=1).encode("utf-8"))
