"""Errors raised for bad input: each names the file and the field at fault."""

from __future__ import annotations

from pathlib import Path


class FgcalError(Exception):
    """Base class of fgcal's own errors; the CLI prints these without a traceback."""


class InputError(FgcalError):
    """A user file is missing, malformed or inconsistent.

    ``source`` is the file (or a description of the in-memory input) and ``field`` the
    dotted path of the offending entry, e.g. ``joints[2].alpha``.
    """

    def __init__(self, source: str | Path | None, field: str | None, message: str) -> None:
        self.source = str(source) if source is not None else None
        self.field = field
        self.message = message
        where = ": ".join(part for part in (self.source, self.field) if part)
        super().__init__(f"{where}: {message}" if where else message)
