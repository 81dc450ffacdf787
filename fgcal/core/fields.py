"""Validated access to fields of YAML documents, so every error names file and field."""

from __future__ import annotations

import math
import re
import stat
from collections.abc import Hashable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .errors import InputError

_MISSING = object()


MAX_FILE_BYTES = 1 << 28  # 256 MB: no file fgcal reads is larger; /dev/zero would never end


def read_file_text(path: str | Path, encoding: str = "utf-8", limit: int = MAX_FILE_BYTES) -> str:
    """A regular file's text; a missing, special (a FIFO, a device) or huge file, or one that is
    not text in ``encoding``, is an :class:`InputError` (LookupError for an unknown encoding)."""
    path = Path(path)
    try:
        info = path.stat()
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except OSError as exc:
        raise InputError(path, None, f"cannot read file: {exc.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        raise InputError(path, None, "not a regular file (a folder, a FIFO or a device)")
    if info.st_size > limit:
        raise InputError(path, None, f"larger than {limit >> 20} MB: not a file fgcal reads")
    try:
        return path.read_text(encoding=encoding)
    except UnicodeDecodeError as exc:
        raise InputError(path, None, f"not {encoding} text: {exc.reason} at byte {exc.start}") from None
    except OSError as exc:
        raise InputError(path, None, f"cannot read file: {exc}") from None


class _DuplicateKey(yaml.MarkedYAMLError):
    pass


class _UniqueKeyLoader(yaml.SafeLoader):
    """yaml.SafeLoader that refuses a key given twice in one mapping: PyYAML keeps the last one
    silently, and a config with validation: typed twice ran on the second."""

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.get(key)
            except TypeError:  # an unhashable key: the base class says so
                break
            if first is not None:
                raise _DuplicateKey(None, None, f"key {key!r} given twice (first on line {first})", key_node.start_mark)
            seen[key] = key_node.start_mark.line + 1
        return super().construct_mapping(node, deep)


def read_yaml(path: str | Path) -> Any:
    """Safely load a YAML file (yaml.SafeLoader, refusing a key given twice); unreadable or
    malformed files raise :class:`InputError`."""
    path = Path(path)
    text = read_file_text(path)
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise InputError(path, None, f"malformed YAML: {where}{problem}") from None


class Fields:
    """A mapping read from ``source`` at dotted location ``prefix``.

    Getters check type, finiteness and shape and raise :class:`InputError` naming the field.
    """

    def __init__(self, data: object, source: str | Path, prefix: str = "") -> None:
        if not isinstance(data, Mapping):
            raise InputError(source, prefix or None, f"expected a mapping, got {type(data).__name__}")
        self.data = data
        self.source = source
        self.prefix = prefix

    def path(self, key: str) -> str:
        return f"{self.prefix}.{key}" if self.prefix else key

    def error(self, key: str, message: str) -> InputError:
        return InputError(self.source, self.path(key), message)

    def has(self, key: str) -> bool:
        """Whether the document gives ``key``. A key given as null is given: null is a value,
        read as "none" where a field documents it (``nullable``) and refused elsewhere, never
        silently taken for the default."""
        return key in self.data

    def check_keys(self, allowed: Sequence[str]) -> None:
        """Reject unknown keys: a typo in a field name must not be silently ignored."""
        for key in self.data:
            if key not in allowed:
                raise self.error(str(key), f"unknown field (allowed: {', '.join(allowed)})")

    def check_format(self, expected: str) -> None:
        """The document's ``format`` field names the format this fgcal reads."""
        fmt = self.string("format")
        if fmt != expected:
            raise self.error("format", f"unsupported format {fmt!r} (this fgcal reads {expected})")

    def raw(self, key: str, default: Any = _MISSING, *, nullable: bool = False) -> Any:
        """The value of ``key``; ``default`` when it is absent. A null value is returned as None
        where the field is ``nullable`` (it documents null, e.g. "no robust loss") and refused
        elsewhere: a null that would silently mean the default is the bug this prevents."""
        if not self.has(key):
            if default is _MISSING:
                raise self.error(key, "required field is missing")
            return default
        value = self.data[key]
        if value is None and not nullable:
            hint = "give a value" if default is _MISSING else "give a value, or leave the field out for its default"
            raise self.error(key, f"is null: {hint}")
        return value

    def sub(self, key: str, default: Any = _MISSING) -> Fields:
        # A section given as null (``robust: null``, or ``noise:`` with nothing under it) is
        # refused as any null is: "robust: null" reads as "no robust loss" to a person, and
        # taking it for the defaults would be silently wrong.
        value = self.raw(key, default)
        return Fields(value if value is not None else {}, self.source, self.path(key))

    def items(self, key: str, default: Any = _MISSING) -> list[Fields | Any]:
        value = self.raw(key, default)
        if not isinstance(value, list):
            raise self.error(key, f"expected a list, got {type(value).__name__}")
        return value

    def sub_list(self, key: str, default: Any = _MISSING) -> list[Fields]:
        return [Fields(item, self.source, f"{self.path(key)}[{i}]") for i, item in enumerate(self.items(key, default))]

    def string(self, key: str, default: Any = _MISSING, choices: Sequence[str] | None = None) -> str:
        value = self.raw(key, default)
        if not isinstance(value, str):
            raise self.error(key, f"expected a string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.error(key, f"{value!r} is not one of {', '.join(choices)}")
        return value

    def number(
        self, key: str, default: Any = _MISSING, scale: float = 1.0, positive: bool = False, nonnegative: bool = False
    ) -> float:
        value = self.raw(key, default)
        number = to_float(value, self.source, self.path(key))
        if positive and not number > 0:
            raise self.error(key, f"must be > 0, got {value!r}")
        if nonnegative and not number >= 0:
            raise self.error(key, f"must be >= 0, got {value!r}")
        return number * scale

    def integer(self, key: str, default: Any = _MISSING, minimum: int | None = None, maximum: int | None = None) -> int:
        value = self.raw(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"expected an integer, got {value!r}")
        if minimum is not None and value < minimum:
            raise self.error(key, f"must be >= {minimum}, got {value}")
        if maximum is not None and value > maximum:
            raise self.error(key, f"must be <= {maximum}, got {value}")
        return value

    def vector(self, key: str, length: int, default: Any = _MISSING, scale: float = 1.0) -> np.ndarray:
        value = self.raw(key, default)
        if not isinstance(value, (list, tuple)) or len(value) != length:
            raise self.error(key, f"expected a list of {length} numbers, got {value!r}")
        return np.array([to_float(v, self.source, f"{self.path(key)}[{i}]") for i, v in enumerate(value)]) * scale


# No field of a robot, cell, dataset header or config is this large in any unit it may use; a
# value such as 1e300 would overflow the algebra downstream instead of being refused here.
MAX_MAGNITUDE = 1e9

_PLAIN_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


def is_plain_number(text: str) -> bool:
    """ASCII decimal notation only (``float`` also takes ``1_000``, full-width digits, nan)."""
    return _PLAIN_NUMBER.fullmatch(text) is not None


def first_repeat(keyed: Iterable[tuple[int, Hashable]]) -> tuple[int, int, Hashable] | None:
    """The first key given twice among (line, key) pairs, as (its first line, the repeat's
    line, the key); None when every key is given once."""
    first_line: dict[Hashable, int] = {}
    for line, key in keyed:
        if key in first_line:
            return first_line[key], line, key
        first_line[key] = line
    return None


def check_name(text: str, source: str | Path, field: str) -> str:
    """A name (a point, a target, a configuration id): printable text, no control characters."""
    if any(ord(c) < 32 or ord(c) == 127 for c in text):
        raise InputError(source, field, f"a name with a control character: {text!r}")
    return text


def to_float(value: Any, source: str | Path, field: str) -> float:
    """A finite float, or an :class:`InputError` naming ``field``.

    YAML 1.1 (PyYAML) reads ``1e-4`` (no dot) as text: such a plain number is accepted."""
    if isinstance(value, str) and is_plain_number(value.strip()):
        value = float(value.strip())  # str.strip takes more than float does (U+001C..U+001F)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError(source, field, f"expected a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise InputError(source, field, f"must be finite, got {value!r}")
    if abs(number) > MAX_MAGNITUDE:
        raise InputError(source, field, f"implausible value {value!r} (beyond {MAX_MAGNITUDE:g})")
    return number
