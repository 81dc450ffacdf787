"""Xacro in: a vendor's robot description as its ROS packages ship it, expanded without ROS.

Vendors ship ``*.xacro`` (macros, includes, ``$(find PKG)``), not URDF. The expansion is the
``xacro`` package's own (the ROS tool, pip-installable). Its ``$(find PKG)`` asks ROS's package
index; here it is the folder given for PKG (``--package NAME=PATH``, or ``--package PATH`` for a
folder named as its package), else, as a workspace lays packages out, a folder named PKG that
is the xacro file or one of its parent folders, or sits beside one of them. Anything the
expansion refuses (a missing package, an undefined property, a broken include) is an
InputError naming the file.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterator, Sequence
from contextvars import ContextVar
from pathlib import Path

from ..core.errors import InputError

SUFFIXES = (".xacro",)
_PACKAGES: ContextVar[dict[str, Path] | None] = ContextVar("fgcal_xacro_packages", default=None)
_LOCK = threading.Lock()  # xacro keeps its state in module globals


def is_xacro(path: str | Path) -> bool:
    return Path(path).suffix.lower() in SUFFIXES


def parse_packages(values: Sequence[str] | None, field: str = "--package") -> dict[str, Path]:
    """``NAME=PATH`` or ``PATH`` (the package named as its folder) each; every folder must exist."""
    out: dict[str, Path] = {}
    for value in values or ():
        name, sep, path = value.partition("=")
        if not sep:
            name, path = Path(value).name, value
        folder = Path(path).expanduser()
        if not name or not path:
            raise InputError(value, field, "give NAME=PATH or a package's folder PATH")
        if not folder.is_dir():
            raise InputError(folder, field, f"no such folder (package {name!r})")
        out[name] = folder.resolve()
    return out


@contextlib.contextmanager
def packages(mapping: dict[str, Path] | None) -> Iterator[None]:
    """Within: ``$(find NAME)`` of any xacro read is ``mapping[NAME]``."""
    token = _PACKAGES.set(dict(mapping or {}))
    try:
        yield
    finally:
        _PACKAGES.reset(token)


def _find(source: Path, name: str) -> Path:
    given = (_PACKAGES.get() or {}).get(name)
    if given is not None:
        return given
    for folder in [source.parent, *source.parent.parents]:
        if folder.name == name:
            return folder
        if (folder / name).is_dir():
            return folder / name
    raise InputError(source, "$(find)", f"no package {name!r}: give its folder with --package {name}=PATH")


def expand(path: str | Path) -> tuple[str, list[Path]]:
    """The URDF text of a xacro file, and the files it read (itself and its includes)."""
    import xacro
    from xacro import substitution_args

    source = Path(path).resolve()
    if not source.is_file():
        raise InputError(path, None, "no such xacro file")
    missing: list[InputError] = []

    def find(name: str) -> str:
        try:
            return str(_find(source, name))
        except InputError as exc:
            missing.append(exc)
            raise

    with _LOCK:
        saved = substitution_args._eval_find, substitution_args._eval_dict["find"]
        substitution_args._eval_find = find
        substitution_args._eval_dict["find"] = find
        xacro.all_includes = []
        try:
            document = xacro.process_file(str(source))
            text = document.toprettyxml(indent="  ")
            read = [source, *(Path(p).resolve() for p in xacro.all_includes)]
        except InputError:
            raise
        except Exception as exc:  # xacro's errors: XacroException, XML, substitution, OS errors
            if missing:
                raise missing[0] from None
            message = " ".join(str(exc).split()) or type(exc).__name__
            raise InputError(path, None, f"xacro failed: {message}") from None
        finally:
            substitution_args._eval_find, substitution_args._eval_dict["find"] = saved
            xacro.all_includes = []
    return text, read
