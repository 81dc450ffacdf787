"""What the commands tell a person: one logger, ``fgcal``, and progress bars.

``say`` (info), ``warn`` and ``detail`` (debug) go through :mod:`logging`, so that ``-q`` keeps
only the warnings, ``-v`` adds the details, and a program embedding fgcal routes them where it
likes. The command line's handler writes plain lines to stdout (to stderr when stdout carries a
JSON object), looked up when each line is written, so that a caller that swaps ``sys.stdout``
sees them.

:class:`Reporter` is what long work is given as ``progress``: called with a line, it says it;
its ``step(label, done, total)`` moves a progress bar (tqdm) when stderr is a terminal, and
does nothing otherwise, so that CI logs hold the lines and no bar.
"""

from __future__ import annotations

import logging
import sys
from typing import Any

LOG = logging.getLogger("fgcal")


def say(message: str) -> None:
    LOG.info(message)


def warn(message: str) -> None:
    LOG.warning(message)


def detail(message: str) -> None:
    LOG.debug(message)


class _Lines(logging.Handler):
    """Plain lines to the stream the command line chose, through tqdm while a bar is shown."""

    def __init__(self, to_stderr: bool) -> None:
        super().__init__()
        self.to_stderr = to_stderr

    def emit(self, record: logging.LogRecord) -> None:
        stream = sys.stderr if self.to_stderr else sys.stdout
        text = self.format(record)
        if record.levelno >= logging.WARNING and not text.startswith("warning"):
            text = f"warning: {text}"
        if _BARS:
            from tqdm import tqdm

            tqdm.write(text, file=stream)
        else:
            stream.write(text + "\n")
            stream.flush()


def setup(verbosity: int = 0, to_stderr: bool = False) -> None:
    """The command line's logging: -q (verbosity -1) warnings only, -v (1) details too."""
    for handler in list(LOG.handlers):
        if isinstance(handler, _Lines):
            LOG.removeHandler(handler)
    handler = _Lines(to_stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    LOG.addHandler(handler)
    LOG.setLevel(logging.WARNING if verbosity < 0 else logging.DEBUG if verbosity > 0 else logging.INFO)
    LOG.propagate = False


_BARS: dict[str, Any] = {}


def interactive() -> bool:
    """Whether a person watches: stderr is a terminal and info lines are shown."""
    return sys.stderr.isatty() and LOG.isEnabledFor(logging.INFO)


class Reporter:
    """``progress`` for long work: lines to the log, bars on a terminal."""

    def __call__(self, message: str) -> None:
        say(message)

    def step(self, label: str, done: int, total: int) -> None:
        """``done`` of ``total`` units of the phase ``label``; the bar closes when they are done."""
        if not interactive() or total <= 0:
            return
        from tqdm import tqdm

        bar = _BARS.get(label)
        if bar is None:
            bar = _BARS[label] = tqdm(total=total, desc=label, file=sys.stderr, leave=False, dynamic_ncols=True)
        bar.n = min(done, total)
        bar.refresh()
        if done >= total:
            bar.close()
            del _BARS[label]


def step(progress: object, label: str, done: int, total: int) -> None:
    """Move ``progress``'s bar if it has one (a plain callable has none)."""
    advance = getattr(progress, "step", None)
    if advance is not None:
        advance(label, done, total)
