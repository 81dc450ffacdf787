"""Robot programs' targets: read ABB RAPID modules and KUKA KRL ``.dat`` files, write them back corrected.

Inside, everything is SI: metres, radians, 4x4 homogeneous poses. In the files, positions are in mm,
RAPID orientations are quaternions ``q1..q4 = w x y z`` and KRL orientations are ``A B C`` in degrees
with ``R = Rz(A) Ry(B) Rx(C)``.

:func:`write_program` returns the program's text with only the numbers of the corrected targets
replaced (each number's own characters); comments, spacing, instructions, the external axes and the
line endings stay byte for byte.

RAPID (``.mod``, ``.modx``, ``.prg``, ``.sys``): ``robtarget``, ``tooldata`` and ``wobjdata``
declarations (``CONST``/``PERS``/``VAR``, optionally ``LOCAL``/``TASK``) with literal aggregate
values; comments (``!``) and strings are skipped. Refused (:class:`InputError`): a robtarget whose
value is not a literal aggregate, a malformed or unterminated value, a quaternion of norm outside
0.9..1.1, a name declared twice. Not targets: declarations without a value (``VAR robtarget p;``), routine parameters,
jointtargets, inline targets. Arrays of robtargets, tooldata and wobjdata give one of each per
element, named as RAPID indexes them (``pts{2}``, ``grid{1,3}``). Each target records the tool and
``\\WObj`` of the first MoveL/MoveJ/MoveC (or their DO/Sync variants) using it, directly or through
``Offs(...)``/``RelTool(...)``; an array's element used only through a variable index (``pts{i}``
in a loop) takes that instruction's tool and work object, with no place in the path.

KRL (``.dat``): ``[GLOBAL] [DECL] E6POS|POS NAME={...}`` on one line, components in any order,
``S``/``T`` as decimal integers or ``'B...'``/``'H...'`` literals (written back in the same style).
Arrays: ``DECL E6POS XPS[3]`` then ``XPS[1]={X ...}`` lines, one target per element (``XPS[1]``).
Refused: a target missing one of X Y Z A B C, a malformed component, an element outside its array.
Everything else (FDAT, PDAT, LDAT, E6AXIS, AXIS, FRAME, comments after ``;``) is left alone.
"""

from __future__ import annotations

import bisect
import codecs
import math
import re
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np

from fgcal.core import se3
from fgcal.core.errors import InputError
from fgcal.core.fields import read_file_text

RAPID_SUFFIXES = (".mod", ".modx", ".prg", ".sys")
KRL_SUFFIXES = (".dat",)
MM = 1e-3  # metres per millimetre
QUATERNION_NORM_RANGE = (0.9, 1.1)
GIMBAL_LOCK_RAD = 1e-9  # |cos B| below this: B is +-90 deg and C is written as 0

_RAPID_POSE_KEYS = ("x", "y", "z", "q1", "q2", "q3", "q4")
_RAPID_CONF_KEYS = ("cf1", "cf4", "cf6", "cfx")
_KRL_POSE_KEYS = ("X", "Y", "Z", "A", "B", "C")
_KRL_CONF_KEYS = ("S", "T")


@dataclass(frozen=True)
class ProgramTarget:
    """A target declared in a program; ``pose`` is the TCP in the program's frame (m, rad)."""

    name: str
    line: int  # 1-based line of the declaration
    pose: np.ndarray  # (4, 4), metres
    config: dict[str, int]  # RAPID: cf1, cf4, cf6, cfx; KRL: S and T when given
    tool: str | None = None  # RAPID: the tool of the first motion instruction using it; KRL: its FDAT's TOOL_DATA[n]
    work_object: str | None = None  # RAPID: the \WObj of that instruction; KRL: its FDAT's BASE_DATA[m]
    spans: Mapping[str, tuple[int, int]] = field(default_factory=dict, repr=False)
    """Character offsets ``[start, end)`` into ``Program.text`` of each value (RAPID: x y z q1..q4
    cf1 cf4 cf6 cfx; KRL: X Y Z A B C and S T when given)."""
    first_move: int | None = None  # RAPID: ordinal of the first motion to the target itself (text order)
    moves: int = 0  # RAPID: how many motion instructions use it (Offs/RelTool of it too)
    approached_from: str | None = None  # RAPID: the target the robot comes from there (None: unknown)
    fixed_tool: bool = False  # KRL: its FDAT's IPO_FRAME #TCP (an external TCP: the part moves)
    tool_load: str | None = None  # RAPID: the loaddata of that instruction's \TLoad (it replaces the tool's)
    external_axes: bool = False  # an external axis's value given (RAPID: not 9E9; KRL: E1..E6 not 0)


@dataclass(frozen=True)
class ToolData:
    """A RAPID tooldata: TCP frame and load in the flange frame (m, kg)."""

    tcp: np.ndarray  # (4, 4), metres
    mass_kg: float
    cog_m: np.ndarray  # (3,), metres
    robhold: bool


@dataclass(frozen=True)
class JointTarget:
    """A joint position a program declares: RAPID ``jointtarget`` (its robax), KRL ``E6AXIS`` or
    ``AXIS`` (A1..A6), in degrees as written (a prismatic axis: mm)."""

    name: str
    line: int
    joints_deg: np.ndarray  # (6,)


@dataclass(frozen=True)
class Program:
    """A robot program as read: its exact text and the targets, tools and work objects declared in it."""

    path: Path
    kind: str  # "rapid" or "krl"
    text: str  # exactly as in the file (line endings kept)
    targets: tuple[ProgramTarget, ...]
    tools: dict[str, ToolData]  # RAPID tooldata; KRL: TOOL_DATA[n] from --declarations (else empty)
    work_objects: dict[str, np.ndarray]  # RAPID wobjdata: uframe @ oframe; KRL: BASE_DATA[m]; (4, 4) m
    encoding: str = "utf-8"  # "latin-1" when the file is not UTF-8: write the new text back with it
    declared_in: dict[str, str] = field(default_factory=dict)  # lower-case name -> the file (--declarations)
    loads: dict[str, tuple[float, np.ndarray]] = field(default_factory=dict)  # RAPID loaddata: kg, centre of mass m


# ---------------------------------------------------------------------------------------------
# Reading


def read_program(path: str | Path) -> Program:
    """Read a RAPID module or a KRL ``.dat`` file, chosen by the suffix; bad input is an InputError."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in RAPID_SUFFIXES + KRL_SUFFIXES:
        accepted = ", ".join(RAPID_SUFFIXES + KRL_SUFFIXES)
        raise InputError(path, None, f"unknown program suffix {path.suffix or '(none)'!r}: expected one of {accepted}")
    if path.is_file() and path.stat().st_size > MAX_PROGRAM_BYTES:
        raise InputError(
            path, None, f"{path.stat().st_size / 1e6:.0f} MB: a program is at most {MAX_PROGRAM_BYTES // 10**6} MB"
        )
    text, encoding = _read_text(path)
    if "\r" in text and "\n" not in text:
        raise InputError(path, None, "its lines end in CR alone (classic Mac OS): convert them to LF or CR LF")
    try:
        if suffix in KRL_SUFFIXES:
            return Program(path, "krl", text, _krl_targets(text, path), {}, {}, encoding)
        targets, tools, work_objects, loads = _read_rapid(text, path)
    except RecursionError:
        raise InputError(path, None, "brackets nested too deeply for a robot program") from None
    return Program(path, "rapid", text, targets, tools, work_objects, encoding, loads=loads)


MAX_PROGRAM_BYTES = 32 * 10**6  # a 32 MB module holds some 200 000 targets
MAX_VALUE = 1e10  # beyond this a number is a typo (9E+09 is RAPID's unused external axis)


# A motion whose first positional argument is a literal (after any switches: MoveJ \\Conc, [[...]]).
_INLINE = re.compile(
    r"\b(Move[A-Za-z]*|Search[A-Za-z]*|Arc[A-Za-z]*|Trigg[A-Za-z]*)\s*(\\\w+\s*,?\s*)*\[\s*\[", re.IGNORECASE
)


_KRL_INLINE = re.compile(r"^\s*(?:S?PTP|S?LIN|S?CIRC)\b[^;]*\{\s*(?:[A-Za-z_]\w*\s*:\s*)?[XYZ]\s", re.IGNORECASE)


def src_beside(dat: Path) -> Path | None:
    """The KRL ``.src`` of the same name beside a ``.dat`` (KUKA's file names are not case-sensitive:
    PALLET.dat goes with pallet.src)."""
    try:
        entries = list(dat.parent.iterdir())
    except OSError:
        return None
    return next((p for p in sorted(entries) if p.stem.lower() == dat.stem.lower() and p.suffix.lower() == ".src"
                 and p.is_file()), None)  # fmt: skip


def krl_inline_targets(program: Program) -> tuple[Path | None, list[int]]:
    """The ``.src`` beside a KRL ``.dat`` (the same name) and the lines of its motions whose
    Cartesian target is written inline (``LIN {X 1000, ...}``): they are not in the .dat, so
    they are listed rather than silently kept. (None, []) without a .src or for RAPID."""
    if program.kind != "krl":
        return None, []
    source = src_beside(program.path)
    if source is None:
        return None, []
    try:
        text, _ = _read_text(source)
    except InputError:
        return source, []  # unreadable: the .dat is what is corrected
    return source, [n for n, line in enumerate(text.splitlines(), 1) if _KRL_INLINE.match(line)]


def inline_targets(program: Program) -> list[int]:
    """Lines of a RAPID module's motions whose target is written inline (``MoveL [[x, y, z],
    ...], ...``): no name to correct it by, so they are listed rather than silently kept."""
    if program.kind != "rapid":
        return []
    lines = []
    for number, line in enumerate(program.text.splitlines(), start=1):
        code = re.sub(r'"[^"]*"', '""', line).split("!", 1)[0]  # no strings; a comment, from its mark
        if _INLINE.search(code):
            lines.append(number)
    return lines


def _read_text(path: Path) -> tuple[str, str]:
    """The file's exact text (no newline translation) and its encoding, written back the same:
    UTF-16 or UTF-8 with a byte-order mark (editors on Windows save so), else UTF-8, else Latin-1.
    UTF-16 read as Latin-1 had a NUL between every character, and no target was found."""
    read_file_text(path, encoding="latin-1")  # the checks: exists, a regular file, not huge
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(path, None, f"cannot read file: {exc.strerror}") from None
    for mark, encoding in ((codecs.BOM_UTF8, "utf-8-sig"), (codecs.BOM_UTF16_LE, "utf-16"),
                           (codecs.BOM_UTF16_BE, "utf-16")):  # fmt: skip
        if data.startswith(mark):
            try:
                return data.decode(encoding), encoding
            except UnicodeDecodeError as exc:
                raise InputError(path, None, f"not {encoding} text after its byte-order mark: {exc.reason}") from None
    if b"\x00" in data:
        raise InputError(path, None, "NUL bytes: UTF-16 without a byte-order mark, or not a program; save it as UTF-8")
    try:
        return data.decode("utf-8"), "utf-8"
    except UnicodeDecodeError:
        return data.decode("latin-1"), "latin-1"


def _line_starts(text: str) -> list[int]:
    return [0, *(m.end() for m in re.finditer("\n", text))]


# ---------------------------------------------------------------------------------------------
# RAPID tokens and values

_RAPID_TOKEN = re.compile(
    r"""(?P<space>\s+)
    |(?P<comment>![^\r\n]*)
    |(?P<string>"(?:[^"\r\n]|"")*")
    |(?P<number>(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?)
    |(?P<name>[A-Za-z_][A-Za-z0-9_]*)
    |(?P<assign>:=)
    |(?P<other>.)""",
    re.VERBOSE | re.DOTALL,
)


class _Token(NamedTuple):
    kind: str  # "string", "number", "name", "assign" or "other"
    text: str
    start: int
    end: int
    line: int


class _Leaf(NamedTuple):
    """A scalar in an aggregate value: a (signed) number, a name or a string."""

    kind: str
    text: str
    start: int
    end: int
    line: int


_Node = _Leaf | list


def _rapid_tokens(text: str) -> list[_Token]:
    """Tokens of a RAPID module, comments and blanks dropped."""
    starts = _line_starts(text)
    return [
        _Token(m.lastgroup or "other", m.group(), m.start(), m.end(), bisect.bisect_right(starts, m.start()))
        for m in _RAPID_TOKEN.finditer(text)
        if m.lastgroup not in ("space", "comment")
    ]


@dataclass
class _Context:
    """Where a declaration is being parsed, for error messages."""

    text: str
    tokens: list[_Token]
    path: Path
    name: str
    line: int

    def fail(self, line: int, message: str) -> InputError:
        return InputError(self.path, f"line {line}, {self.name}", message)

    def at(self, i: int) -> _Token:
        if i >= len(self.tokens):
            raise self.fail(self.line, "unterminated declaration: the file ends before its ';'")
        return self.tokens[i]


def _parse_value(i: int, ctx: _Context) -> tuple[_Node, int]:
    """The aggregate or scalar starting at token ``i`` and the index after it."""
    tok = ctx.at(i)
    if tok.text == "[":
        items: list[_Node] = []
        i += 1
        while True:
            item, i = _parse_value(i, ctx)
            items.append(item)
            tok = ctx.at(i)
            if tok.text == "]":
                return items, i + 1
            if tok.text != ",":
                raise ctx.fail(tok.line, f"expected ',' or ']' but found {tok.text!r}")
            i += 1
    if tok.text in ("+", "-"):
        number = ctx.at(i + 1)
        if number.kind != "number":
            raise ctx.fail(number.line, f"expected a number after {tok.text!r} but found {number.text!r}")
        return _Leaf("number", ctx.text[tok.start : number.end], tok.start, number.end, tok.line), i + 2
    if tok.kind in ("number", "name", "string"):
        return _Leaf(tok.kind, tok.text, tok.start, tok.end, tok.line), i + 1
    raise ctx.fail(tok.line, f"expected a value but found {tok.text!r}")


def _first_line(node: _Node, ctx: _Context) -> int:
    while isinstance(node, list):
        if not node:
            return ctx.line
        node = node[0]
    return node.line


def _aggregate(node: _Node, count: int, what: str, ctx: _Context) -> list[_Node]:
    """``node`` as an aggregate of ``count`` items."""
    if not isinstance(node, list) or len(node) != count:
        found = f"{len(node)} items" if isinstance(node, list) else repr(node.text)
        raise ctx.fail(_first_line(node, ctx), f"{what}: expected [...] of {count} items, found {found}")
    return node


def _number(node: _Node, what: str, ctx: _Context) -> float:
    if not isinstance(node, _Leaf) or node.kind != "number":
        text = node.text if isinstance(node, _Leaf) else "[...]"
        raise ctx.fail(_first_line(node, ctx), f"{what}: {text!r} is not a number")
    try:
        value = float(re.sub(r"\s+", "", node.text))
    except ValueError:  # a comment between a sign and its digits
        raise ctx.fail(node.line, f"{what}: {node.text!r} is not a plain number") from None
    if not math.isfinite(value) or abs(value) > MAX_VALUE:
        raise ctx.fail(node.line, f"{what}: {node.text!r} is out of range (beyond {MAX_VALUE:g})")
    return value


def _numbers(node: _Node, count: int, what: str, ctx: _Context) -> tuple[list[float], list[_Leaf]]:
    """``[n1, ..., n_count]``: the values and their leaves."""
    items = _aggregate(node, count, what, ctx)
    values = [_number(item, what, ctx) for item in items]
    return values, [item for item in items if isinstance(item, _Leaf)]


def _boolean(node: _Node, what: str, ctx: _Context) -> bool:
    if isinstance(node, _Leaf) and node.kind == "name" and node.text.upper() in ("TRUE", "FALSE"):
        return node.text.upper() == "TRUE"
    raise ctx.fail(_first_line(node, ctx), f"{what}: expected TRUE or FALSE")


def _unit_quaternion(values: list[float], line: int, what: str, ctx: _Context) -> np.ndarray:
    """The quaternion ``[w, x, y, z]`` normalised; a norm outside 0.9..1.1 is refused."""
    norm = math.hypot(*values)
    low, high = QUATERNION_NORM_RANGE
    if not low <= norm <= high:
        raise ctx.fail(line, f"{what}: quaternion {values} has norm {norm:.6g}, not 1 (allowed {low}..{high})")
    return np.array(values) / norm


def _frame(node: _Node, what: str, ctx: _Context) -> np.ndarray:
    """``[[x, y, z], [q1, q2, q3, q4]]`` (mm, w x y z) as a 4x4 pose in metres."""
    trans_node, rot_node = _aggregate(node, 2, what, ctx)
    trans, _ = _numbers(trans_node, 3, f"{what} position", ctx)
    quat, leaves = _numbers(rot_node, 4, f"{what} orientation", ctx)
    q = _unit_quaternion(quat, leaves[0].line, f"{what} orientation", ctx)
    return se3.pose(se3.quaternion_rotation(q), np.array(trans) * MM)


def _integers(values: list[float], leaves: list[_Leaf], what: str, ctx: _Context) -> list[int]:
    for value, leaf in zip(values, leaves, strict=True):
        if value != int(value):
            raise ctx.fail(leaf.line, f"{what}: {leaf.text!r} is not an integer")
    return [int(v) for v in values]


# ---------------------------------------------------------------------------------------------
# RAPID declarations


_STORAGE = ("const", "pers", "var")
_DATA_TYPES = ("robtarget", "tooldata", "wobjdata", "loaddata")


class _Declaration(NamedTuple):
    data_type: str  # "robtarget", "tooldata" or "wobjdata"
    ctx: _Context
    value: _Node


def _rapid_declarations(
    text: str, tokens: list[_Token], path: Path, types: tuple[str, ...] = _DATA_TYPES
) -> Iterator[_Declaration]:
    """The declarations of robtarget, tooldata and wobjdata with a value, in order; an array's
    elements each as a declaration of its own, named as RAPID names them (``pts{2}``, ``grid{1,3}``)."""
    i = 0
    while i < len(tokens) - 2:
        tok, kind, name = tokens[i], tokens[i + 1], tokens[i + 2]
        is_declaration = tok.kind == "name" and tok.text.lower() in _STORAGE and name.kind == "name"
        if is_declaration and kind.kind == "name" and kind.text.lower() in types:
            ctx = _Context(text, tokens, path, name.text, tok.line)
            declarations, i = _parse_declaration(kind.text.lower(), i + 3, ctx)
            yield from declarations
        else:
            i += 1


MAX_ARRAY_ELEMENTS = 10**6  # more elements than a 32 MB module can hold: a typo in the dimensions


def _parse_declaration(data_type: str, i: int, ctx: _Context) -> tuple[list[_Declaration], int]:
    """The declaration whose name ends before token ``i`` (an array's elements: several); none
    if it has no value or is a routine's parameter."""
    written: list[_Token] = []
    if ctx.at(i).text == "{":
        i += 1
        while ctx.at(i).text != "}":
            written += [ctx.at(i)] if ctx.at(i).text != "," else []
            i += 1
        i += 1
    if i >= len(ctx.tokens) or ctx.tokens[i].kind != "assign":
        return [], i  # no value (VAR robtarget p;), or a routine's parameter (q{*})
    dimensions: list[int] = []
    for tok in written:
        if tok.kind != "number" or not tok.text.isdigit() or int(tok.text) < 1:
            raise ctx.fail(tok.line, f"array dimension {tok.text!r}: expected a whole number of at least 1")
        dimensions.append(int(tok.text))
    if math.prod(dimensions) > MAX_ARRAY_ELEMENTS:
        raise ctx.fail(ctx.line, f"an array of {math.prod(dimensions)} elements: at most {MAX_ARRAY_ELEMENTS}")
    value, i = _parse_value(i + 1, ctx)
    end = ctx.at(i)
    if end.text != ";":
        raise ctx.fail(end.line, f"expected ';' after the value but found {end.text!r}")
    if not dimensions:
        return [_Declaration(data_type, ctx, value)], i + 1
    return [
        _Declaration(data_type, replace(ctx, name=f"{ctx.name}{{{','.join(map(str, index))}}}",
                                        line=_first_line(element, ctx)), element)
        for index, element in _elements(value, dimensions, ctx)
    ], i + 1  # fmt: skip


def _elements(value: _Node, dimensions: list[int], ctx: _Context, index: tuple[int, ...] = ()):
    """An array value's elements with their (1-based) indices, row by row as RAPID writes them:
    ``{2,3}`` is ``[[e11, e12, e13], [e21, e22, e23]]``."""
    items = _aggregate(value, dimensions[0], f"array of {'x'.join(map(str, dimensions))} elements", ctx)
    for k, item in enumerate(items, 1):
        if len(dimensions) == 1:
            yield (*index, k), item
        else:
            yield from _elements(item, dimensions[1:], ctx, (*index, k))


def _robtarget(value: _Node, ctx: _Context) -> ProgramTarget:
    """``[[x,y,z],[q1..q4],[cf1,cf4,cf6,cfx],[eax_a..eax_f]]`` as a target (mm -> m)."""
    what = "robtarget [[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[eax_a,...,eax_f]]"
    trans_node, rot_node, conf_node, extax_node = _aggregate(value, 4, what, ctx)
    trans, trans_leaves = _numbers(trans_node, 3, "position [x,y,z]", ctx)
    quat, quat_leaves = _numbers(rot_node, 4, "orientation [q1,q2,q3,q4]", ctx)
    conf, conf_leaves = _numbers(conf_node, 4, "robconf [cf1,cf4,cf6,cfx]", ctx)
    extax, _ = _numbers(extax_node, 6, "external axes", ctx)
    q = _unit_quaternion(quat, quat_leaves[0].line, "orientation", ctx)
    config = dict(zip(_RAPID_CONF_KEYS, _integers(conf, conf_leaves, "robconf", ctx), strict=True))
    leaves = trans_leaves + quat_leaves + conf_leaves
    spans = {key: (leaf.start, leaf.end) for key, leaf in zip(_RAPID_POSE_KEYS + _RAPID_CONF_KEYS, leaves, strict=True)}
    pose = se3.pose(se3.quaternion_rotation(q), np.array(trans) * MM)
    moved = any(abs(v) < RAPID_UNUSED_AXIS for v in extax)  # 9E9: the axis is not used
    return ProgramTarget(ctx.name, ctx.line, pose, config, spans=spans, external_axes=moved)


RAPID_UNUSED_AXIS = 8.9e9  # RAPID's 9E9 (9E+09) marks an unused external axis


def _tooldata(value: _Node, ctx: _Context) -> ToolData:
    """``[robhold, [[x,y,z],[q]], [mass, [cx,cy,cz], [aq1..aq4], ix, iy, iz]]`` (mm, kg)."""
    what = "tooldata [robhold, tframe, tload]"
    robhold, tframe, tload = _aggregate(value, 3, what, ctx)
    mass, cog = _load(tload, "tload [mass, cog, aom, ix, iy, iz]", ctx)
    tcp = _frame(tframe, "tframe", ctx)
    return ToolData(tcp, mass, cog, _boolean(robhold, "robhold", ctx))


def _load(node: _Node, what: str, ctx: _Context) -> tuple[float, np.ndarray]:
    """A loaddata ``[mass, [cx, cy, cz], [aom q1..q4], ix, iy, iz]``: kg and the centre of mass (m)."""
    name = what.split(" ")[0]
    mass_node, cog_node, aom_node, *inertia = _aggregate(node, 6, what, ctx)
    cog, _ = _numbers(cog_node, 3, f"{name} cog", ctx)
    _numbers(aom_node, 4, f"{name} aom", ctx)
    for item in inertia:
        _number(item, f"{name} inertia", ctx)
    mass = _number(mass_node, f"{name} mass", ctx)
    if not 0.0 <= mass <= MAX_LOAD_KG or np.abs(cog).max() > MAX_COG_MM:
        raise ctx.fail(
            _first_line(node, ctx), f"{name}: a mass of 0 to {MAX_LOAD_KG:g} kg and a cog within {MAX_COG_MM:g} mm, "
            f"got {mass:g} kg at {[float(v) for v in cog]}",
        )  # fmt: skip
    return mass, np.array(cog) * MM


MAX_LOAD_KG, MAX_COG_MM = 10000.0, 10000.0


def _wobjdata(value: _Node, ctx: _Context) -> np.ndarray:
    """``[robhold, ufprog, "ufmec", uframe, oframe]`` as uframe @ oframe (m)."""
    robhold, ufprog, ufmec, uframe, oframe = _aggregate(value, 5, "wobjdata", ctx)
    if not (isinstance(ufmec, _Leaf) and ufmec.kind == "string"):
        raise ctx.fail(_first_line(ufmec, ctx), 'ufmec: expected a string ("")')
    if _boolean(robhold, "robhold", ctx) or not _boolean(ufprog, "ufprog", ctx):
        raise ctx.fail(
            _first_line(value, ctx), "a work object held by the robot (robhold TRUE) or moved by a mechanical unit "
            "(ufprog FALSE) is not supported: its targets move with it",
        )  # fmt: skip
    return _frame(uframe, "uframe", ctx) @ _frame(oframe, "oframe", ctx)


def _read_rapid(text: str, path: Path):
    """A RAPID module's targets, tools, work objects and loads (loaddata)."""
    tokens = _rapid_tokens(text)
    targets: list[ProgramTarget] = []
    tools: dict[str, ToolData] = {}
    work_objects: dict[str, np.ndarray] = {}
    loads: dict[str, tuple[float, np.ndarray]] = {}
    seen: dict[str, int] = {}
    for declaration in _rapid_declarations(text, tokens, path):
        ctx = declaration.ctx
        if ctx.name.lower() in seen:
            raise ctx.fail(ctx.line, f"declared twice (first on line {seen[ctx.name.lower()]})")
        seen[ctx.name.lower()] = ctx.line
        if declaration.data_type == "robtarget":
            targets.append(_robtarget(declaration.value, ctx))
        elif declaration.data_type == "tooldata":
            tools[ctx.name] = _tooldata(declaration.value, ctx)
        elif declaration.data_type == "loaddata":
            loads[ctx.name] = _load(declaration.value, "loaddata [mass, cog, aom, ix, iy, iz]", ctx)
        else:
            work_objects[ctx.name] = _wobjdata(declaration.value, ctx)
    uses = _motion_uses(tokens)
    # An array's element goes by its own use (pts{2}), else by a loop's over the array (pts{i}).
    targets = [_with_use(target, _use_of(target.name, uses)) for target in targets]
    return tuple(targets), tools, work_objects, loads


def joint_path(program: Program) -> list[JointTarget]:
    """The joint positions a program drives to, in the order its motions go to them: RAPID
    ``jointtarget``s by its ``MoveAbsJ`` instructions; KRL ``E6AXIS``/``AXIS`` of the ``.dat`` by
    the ``PTP`` motions of the ``.src`` of the same name beside it. Without such motions, in
    declaration order. (Program filtering does not read them: joints need no correction.)"""
    if program.kind == "rapid":
        tokens = _rapid_tokens(program.text)
        declared = [_jointtarget(d.value, d.ctx) for d in _rapid_declarations(program.text, tokens, program.path,
                                                                               ("jointtarget",))]  # fmt: skip
        moves = []
        for i, tok in enumerate(tokens):
            is_move = tok.kind == "name" and tok.text.lower() == "moveabsj"
            if is_move and not (i and tokens[i - 1].text.lower() == "proc"):
                arguments, _ = _instruction_arguments(tokens, i + 1)
                name = _single_name(arguments[0]) if arguments else None
                if name is not None:
                    moves.append(name)
    else:
        declared = list(_krl_joint_targets(program.text, program.path))
        source = src_beside(program.path)
        moves = list(krl_joint_moves(source)) if source is not None else []
    by_name = {target.name.lower(): target for target in declared}
    if not moves:
        return declared
    missing = [name for name in moves if name.lower() not in by_name]
    if missing:
        raise InputError(program.path, None, f"moves to joint positions it does not declare: {', '.join(missing[:5])}")
    return [by_name[name.lower()] for name in moves]


def _jointtarget(value: _Node, ctx: _Context) -> JointTarget:
    """``[[rax_1..rax_6], [eax_a..eax_f]]`` (deg; mm for a linear axis)."""
    robax, extax = _aggregate(value, 2, "jointtarget [[rax_1,...,rax_6],[eax_a,...,eax_f]]", ctx)
    joints, _ = _numbers(robax, 6, "robax [rax_1,...,rax_6]", ctx)
    _numbers(extax, 6, "external axes", ctx)
    return JointTarget(ctx.name, ctx.line, np.array(joints))


def _use_of(name: str, uses: dict[str, _Use]) -> _Use | None:
    """A target's use: its own (``pts{2}``), else a loop's over its array (``pts{i}``: the tool
    and work object, not a place in the path: the loop's order is not known here)."""
    own = uses.get(name.lower())
    if own is not None or "{" not in name:
        return own
    loop = uses.get(name.split("{")[0].lower() + "{*}")
    return None if loop is None else replace(loop, first_plain=None, approached_from=None)


def _with_use(target: ProgramTarget, use: _Use | None) -> ProgramTarget:
    if use is None:
        return target
    return replace(
        target, tool=use.tool, work_object=use.work_object, first_move=use.first_plain, moves=use.count,
        approached_from=use.approached_from, tool_load=use.tool_load,
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------
# RAPID motion instructions

# Instruction -> (number of target arguments, index of the tool among the positional arguments).
_MOTIONS = {
    "movel": (1, 3),
    "movej": (1, 3),
    "movec": (2, 4),
    "moveldo": (1, 3),
    "movejdo": (1, 3),
    "movecdo": (2, 4),
    "movelsync": (1, 3),
    "movejsync": (1, 3),
    "movecsync": (2, 4),
}
_TARGET_FUNCTIONS = ("offs", "reltool")
_OPENING, _CLOSING = frozenset("([{"), frozenset(")]}")


@dataclass
class _Use:
    """How a target is used: the tool and work object of the first motion instruction using it,
    the number of motion instructions using it, the ordinal (text order) of the first that goes
    to the target itself (not to an ``Offs``/``RelTool`` of it), and the target the robot comes
    from there (lower case; None: unknown, an ``Offs``/``RelTool`` point or nothing before)."""

    tool: str | None
    work_object: str | None
    count: int = 1
    tool_load: str | None = None  # the instruction's \TLoad
    first_plain: int | None = None
    approached_from: str | None = None


def _motion_uses(tokens: list[_Token]) -> dict[str, _Use]:
    """Lower-case target name -> its use by the module's motion instructions."""
    uses: dict[str, _Use] = {}
    ordinal = 0
    previous: str | None = None  # the point the robot is at: a plain target, or None (unknown)
    for i, tok in enumerate(tokens):
        spec = _MOTIONS.get(tok.text.lower()) if tok.kind == "name" else None
        if spec is None or (i > 0 and tokens[i - 1].text.lower() == "proc"):
            continue
        arguments, wobj = _instruction_arguments(tokens, i + 1)
        tload = _optional_name(tokens, i + 1, "tload")
        n_targets, tool_index = spec
        tool = _single_name(arguments[tool_index]) if len(arguments) > tool_index else None
        for argument in arguments[:n_targets]:
            name = _target_name(argument)
            plain = _single_name(argument)
            if name is not None:
                name = _array_key(name) or name
                use = uses.setdefault(name.lower(), _Use(tool, wobj, count=0, tool_load=tload))
                use.count += 1
                if plain is not None and use.first_plain is None:
                    use.first_plain, use.approached_from = ordinal, previous
            # A loop's element (pts{i}) is not a place the robot is known to come from.
            previous = plain.lower() if plain is not None and _array_key(plain) is None else None
            ordinal += 1
    return uses


def _instruction_arguments(tokens: list[_Token], i: int) -> tuple[list[list[_Token]], str | None]:
    """The positional arguments (optional ``\\Arg`` parts dropped) up to ``;``, and the ``\\WObj``."""
    arguments: list[list[_Token]] = []
    current: list[_Token] = []
    depth, optional, wobj = 0, False, None
    while i < len(tokens) and not (depth == 0 and tokens[i].text == ";"):
        tok = tokens[i]
        depth += (tok.text in _OPENING) - (tok.text in _CLOSING)
        wobj = _wobj_at(tokens, i) or wobj
        if depth == 0 and tok.text == ",":
            if current:
                arguments.append(current)
            current, optional = [], False
        elif depth == 0 and tok.text == "\\":
            optional = True
        elif not optional:
            current.append(tok)
        i += 1
    if current:
        arguments.append(current)
    return arguments, wobj


def _optional_name(tokens: list[_Token], i: int, argument: str) -> str | None:
    """The name an instruction starting at token ``i`` gives its optional ``\\Argument :=``."""
    while i < len(tokens) and tokens[i].text != ";":
        window = tokens[i : i + 4]
        if len(window) == 4 and window[0].text == "\\" and window[1].text.lower() == argument and \
                window[2].kind == "assign":  # fmt: skip
            return window[3].text if window[3].kind == "name" else None
        i += 1
    return None


def _wobj_at(tokens: list[_Token], i: int) -> str | None:
    """The work object's name if tokens ``i..i+3`` are ``\\WObj := name``."""
    window = tokens[i : i + 4]
    if len(window) == 4 and window[0].text == "\\" and window[1].text.lower() == "wobj" and window[2].kind == "assign":
        if window[3].kind != "name":
            return None
        end = i + 4  # an array's element: wobjs{2}
        if end < len(tokens) and tokens[end].text == "{":
            end = next((k + 1 for k in range(end, len(tokens)) if tokens[k].text in "};"), end)
        return _single_name(tokens[i + 3 : end])
    return None


def _single_name(argument: list[_Token]) -> str | None:
    """A name (``p10``) or an array's element (``pts{2}``, ``guns{i}``: as written, blanks
    dropped); anything else None."""
    if not argument or argument[0].kind != "name":
        return None
    if len(argument) == 1:
        return argument[0].text
    if argument[1].text == "{" and argument[-1].text == "}" and all(t.text not in "{}" for t in argument[2:-1]):
        return argument[0].text + "".join(t.text for t in argument[1:])
    return None


def _target_name(argument: list[_Token]) -> str | None:
    """``p10``, ``Offs(p10, ...)`` or ``RelTool(p10, ...)`` -> ``p10`` (or an array's element);
    anything else None."""
    if len(argument) >= 3 and argument[0].text.lower() in _TARGET_FUNCTIONS and argument[1].text == "(":
        end = 3
        if end < len(argument) and argument[end].text == "{":
            end = next((k + 1 for k in range(end, len(argument)) if argument[k].text == "}"), end)
        return _single_name(argument[2:end])
    return _single_name(argument)


def _array_key(name: str) -> str | None:
    """``pts{i}`` (an index that is not a literal number) -> ``pts{*}``: the key under which
    a loop's use stands for every element of the array; None for other names."""
    if "{" not in name:
        return None
    base, index = name.split("{", 1)
    literal = all(part.strip().isdigit() for part in index.rstrip("}").split(","))
    return None if literal else f"{base}{{*}}"


# ---------------------------------------------------------------------------------------------
# KRL

_KRL_CODE = re.compile(r'(?:"[^"\r\n]*"|[^";\r\n])*')  # a line's code, before any ';' comment
_KRL_DECL = re.compile(r"\s*(?:GLOBAL\s+)?(?:DECL\s+)?(?:GLOBAL\s+)?(E6POS|POS)\s+([A-Za-z_$][\w$]*)", re.IGNORECASE)
_KRL_TYPE_PREFIX = re.compile(r"\s*[A-Za-z_]\w*\s*:(?!=)")
_KRL_COMPONENT = re.compile(r"\s*([A-Za-z_]\w*)\s+(\S(?:.*\S)?)\s*", re.DOTALL)
_KRL_REAL = re.compile(r"[+-]?\s*(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_KRL_INT = re.compile(r"[+-]?[0-9]+")
_KRL_BITS = re.compile(r"'([Bb])([01]+)'|'([Hh])([0-9A-Fa-f]+)'")
_Fail = Callable[[str], InputError]  # builds the error naming the file, line and target


_KRL_FDAT = re.compile(r"\s*(?:GLOBAL\s+)?(?:DECL\s+)?(?:GLOBAL\s+)?FDAT\s+([A-Za-z_$][\w$]*)\s*=\s*\{(.*)\}\s*$",
                       re.IGNORECASE)  # fmt: skip
_KRL_ELEMENT = re.compile(r"\s*([A-Za-z_$][\w$]*)\s*\[([0-9,\s]+)\]")
_KRL_DIMENSIONS = re.compile(r"\s*\[\s*([0-9]+(?:\s*,\s*[0-9]+)*)\s*\]")
_KRL_FDAT_FIELD = re.compile(r"(TOOL_NO|BASE_NO)\s+([0-9]+)|IPO_FRAME\s+#(\w+)", re.IGNORECASE)


def _krl_targets(text: str, path: Path) -> tuple[ProgramTarget, ...]:
    """The E6POS and POS targets of a KRL ``.dat`` file, each with the tool and base its FDAT
    names (the inline forms' ``XP1`` and ``FP1``: ``TOOL_DATA[n]``, ``BASE_DATA[m]``; 0 is the
    flange or the robot's base frame)."""
    targets: list[ProgramTarget] = []
    seen: dict[str, int] = {}
    motion_data: dict[str, tuple[str | None, str | None, bool]] = {}
    arrays: dict[str, list[int]] = {}  # lower-case name -> its dimensions
    for number, start in enumerate(_line_starts(text), 1):
        code = _KRL_CODE.match(text, start).group()
        fdat = _KRL_FDAT.match(code)
        if fdat is not None:
            fields = {m.group(1).upper() if m.group(1) else "IPO_FRAME": m.group(2) or m.group(3).upper()
                      for m in _KRL_FDAT_FIELD.finditer(fdat.group(2))}  # fmt: skip
            tool, base = int(fields.get("TOOL_NO", 0)), int(fields.get("BASE_NO", 0))
            motion_data[fdat.group(1).lower()] = (
                f"TOOL_DATA[{tool}]" if tool else None, f"BASE_DATA[{base}]" if base else None,
                fields.get("IPO_FRAME") == "TCP",
            )  # fmt: skip
            continue
        match = _KRL_DECL.match(code)
        element = _KRL_ELEMENT.match(code) if match is None else None
        if element is not None and element.group(1).lower() in arrays:  # XPS[2]={X ...}: an array's element
            name = element.group(1) + "[" + re.sub(r"\s+", "", element.group(2)) + "]"
            fail = partial(InputError, path, f"line {number}, {name}")
            index = [int(v) for v in name[name.index("[") + 1 : -1].split(",")]
            size = arrays[element.group(1).lower()]
            if len(index) != len(size) or any(not 1 <= i <= n for i, n in zip(index, size, strict=False)):
                raise fail(f"index outside the array's declared size [{','.join(map(str, size))}]")
            target = _krl_target(code, element.end(), start, name, number, fail)
        elif match is None:
            continue
        else:
            name = match.group(2)
            dimensions = _KRL_DIMENSIONS.match(code, match.end())
            if dimensions is not None:  # DECL E6POS XPS[3]: its elements follow, one a line
                sizes = [int(v) for v in dimensions.group(1).split(",")]
                if min(sizes) < 1 or code[dimensions.end() :].strip():
                    raise InputError(path, f"line {number}, {name}", "an array of positions is declared as "
                                     "DECL E6POS NAME[n] and given element by element: NAME[1]={X ...}")  # fmt: skip
                arrays[name.lower()] = sizes
                continue
            target = _krl_target(code, match.end(), start, name, number, partial(InputError, path,
                                                                                 f"line {number}, {name}"))
        field_name = f"line {number}, {name}"
        if target is None:
            continue
        if name.lower() in seen:
            raise InputError(path, field_name, f"declared twice (first on line {seen[name.lower()]})")
        seen[name.lower()] = number
        targets.append(target)
    out = []
    for target in targets:
        data = motion_data.get("f" + target.name[1:].lower()) if target.name[:1] in "xX" else None
        if data is not None:
            target = replace(target, tool=data[0], work_object=data[1], fixed_tool=data[2])
        out.append(target)
    return tuple(out)


_KRL_AXIS_DECL = re.compile(r"\s*(?:GLOBAL\s+)?(?:DECL\s+)?(?:GLOBAL\s+)?(E6AXIS|AXIS)\s+([A-Za-z_$][\w$]*)\s*=\s*\{",
                            re.IGNORECASE)  # fmt: skip


def _krl_joint_targets(text: str, path: Path) -> tuple[JointTarget, ...]:
    """The E6AXIS and AXIS declarations of a KRL ``.dat`` (A1..A6, deg)."""
    out = []
    for number, start in enumerate(_line_starts(text), 1):
        code = _KRL_CODE.match(text, start).group()
        match = _KRL_AXIS_DECL.match(code)
        if match is None:
            continue
        name = match.group(2)
        fail = partial(InputError, path, f"line {number}, {name}")
        close_at = code.find("}", match.end())
        if close_at < 0:
            raise fail("unterminated value: no '}' on the line")
        prefix = _KRL_TYPE_PREFIX.match(code, match.end(), close_at)
        components = _krl_components(code, prefix.end() if prefix else match.end(), close_at, start, fail)
        missing = [f"A{i}" for i in range(1, 7) if f"A{i}" not in components]
        if missing:
            raise fail(f"missing {', '.join(missing)}: an axis position needs A1 to A6")
        out.append(JointTarget(name, number, np.array([_krl_real(f"A{i}", components[f"A{i}"][0], fail)
                                                       for i in range(1, 7)])))  # fmt: skip
    return tuple(out)


_KRL_PTP = re.compile(r"^\s*S?PTP\s+([A-Za-z_$][\w$]*)\b", re.IGNORECASE)


def krl_joint_moves(source: str | Path) -> tuple[str, ...]:
    """The points a KRL ``.src`` moves to with PTP by name, in order (comments skipped)."""
    text, _ = _read_text(Path(source))
    return tuple(m.group(1) for line in text.splitlines() if (m := _KRL_PTP.match(_KRL_CODE.match(line).group())))


def _krl_target(code: str, at: int, offset: int, name: str, line: int, fail: _Fail) -> ProgramTarget | None:
    """The target declared in ``code`` whose name ends at ``at``; None without a value."""
    rest = code[at:]
    if not rest.strip():
        return None
    brace = re.match(r"\s*=\s*\{", rest)
    if brace is None:
        raise fail("expected '={X ..,Y ..,Z ..,A ..,B ..,C ..}' after the name")
    open_at = at + brace.end()
    close_at = code.find("}", open_at)
    if close_at < 0:
        raise fail("unterminated value: no '}' on the line")
    if code[close_at + 1 :].strip():
        raise fail(f"unexpected text after '}}': {code[close_at + 1 :].strip()!r}")
    prefix = _KRL_TYPE_PREFIX.match(code, open_at, close_at)
    components = _krl_components(code, prefix.end() if prefix else open_at, close_at, offset, fail)
    return _krl_from_components(components, name, line, fail)


def _krl_components(code: str, start: int, end: int, offset: int, fail: _Fail) -> dict[str, tuple[str, int, int]]:
    """Upper-case component name -> (value text, start, end), offsets into the file's text."""
    components: dict[str, tuple[str, int, int]] = {}
    at = start
    for piece in code[start:end].split(","):
        match = _KRL_COMPONENT.fullmatch(code, at, at + len(piece))
        at += len(piece) + 1
        if match is None:
            raise fail(f"malformed component {piece.strip()!r}: expected NAME VALUE")
        key = match.group(1).upper()
        if key in components:
            raise fail(f"component {key} given twice")
        components[key] = (match.group(2), offset + match.start(2), offset + match.end(2))
    return components


def _krl_from_components(
    components: dict[str, tuple[str, int, int]], name: str, line: int, fail: _Fail
) -> ProgramTarget:
    missing = [key for key in _KRL_POSE_KEYS if key not in components]
    if missing:
        raise fail(f"missing {', '.join(missing)}: a target needs X, Y, Z, A, B and C")
    values = {key: _krl_real(key, components[key][0], fail) for key in _KRL_POSE_KEYS}
    config = {key: _krl_integer(key, components[key][0], fail) for key in _KRL_CONF_KEYS if key in components}
    spans = {key: components[key][1:] for key in _KRL_POSE_KEYS + _KRL_CONF_KEYS if key in components}
    for key in "ABC":
        if abs(values[key]) > 360.0:  # KRL writes -180..180: beyond a turn is a typo (A 6e5)
            raise fail(f"{key}: {values[key]:g} deg is beyond a turn")
    xyz_m = np.array([values["X"], values["Y"], values["Z"]]) * MM
    rpy_rad = np.radians([values["C"], values["B"], values["A"]])
    moved = any(key in components and _krl_real(key, components[key][0], fail) != 0.0 for key in _KRL_EXTERNAL_KEYS)
    return ProgramTarget(name, line, se3.pose_from_xyz_rpy(xyz_m, rpy_rad), config, spans=spans, external_axes=moved)


_KRL_EXTERNAL_KEYS = ("E1", "E2", "E3", "E4", "E5", "E6")


def _krl_real(key: str, text: str, fail: _Fail) -> float:
    if _KRL_REAL.fullmatch(text) is None:
        raise fail(f"{key}: {text!r} is not a number")
    value = float(re.sub(r"\s+", "", text))
    if not math.isfinite(value) or abs(value) > MAX_VALUE:  # as RAPID's: X 1e300 is a typo, not a place
        raise fail(f"{key}: {text!r} is out of range (beyond {MAX_VALUE:g})")
    return value


def _krl_integer(key: str, text: str, fail: _Fail) -> int:
    """A decimal integer, or a ``'B0110'`` / ``'H1F'`` literal."""
    if _KRL_INT.fullmatch(text):
        return int(text)
    bits = _KRL_BITS.fullmatch(text)
    if bits is None:
        raise fail(f"{key}: {text!r} is not an integer (decimal, 'B...' or 'H...')")
    return int(bits.group(2), 2) if bits.group(1) else int(bits.group(4), 16)


# ---------------------------------------------------------------------------------------------
# Declarations held in another file: RAPID's user.sys or a tools module, KUKA's $config.dat

_KRL_SYSTEM = re.compile(
    r"\s*(?:DECL\s+\w+\s+)?(TOOL_DATA|BASE_DATA|LOAD_DATA)\s*\[\s*([0-9]+)\s*\]\s*=\s*\{(.*)\}\s*$", re.IGNORECASE
)
_KRL_LOAD = re.compile(r"\s*M\s+(\S+?)\s*,\s*CM\s*\{([^}]*)\}", re.IGNORECASE)


def with_declarations(program: Program, paths: list[str | Path]) -> Program:
    """The program with the tools and work objects other files declare: RAPID modules
    (``user.sys``: their tooldata and wobjdata), KUKA's ``$config.dat`` (``TOOL_DATA[n]``,
    ``BASE_DATA[m]``, and ``LOAD_DATA[n]`` as tool n's load). A name declared twice, in the
    program and a file or in two files, is refused naming both."""
    tools, objects, found_loads = dict(program.tools), dict(program.work_objects), dict(program.loads)
    where = {name.lower(): program.path for name in [*tools, *objects, *found_loads]}
    for path in map(Path, paths):
        if program.kind == "rapid":
            other = read_program(path)
            if other.kind != "rapid":
                accepted = ", ".join(RAPID_SUFFIXES)
                raise InputError(path, "--declarations", f"a RAPID program takes RAPID modules ({accepted})")
            found_tools, found_objects = other.tools, other.work_objects
            for name in other.loads:
                if name.lower() in where:
                    raise InputError(path, name, f"declared in {where[name.lower()]} too: give one file")
                where[name.lower()] = path
            found_loads.update(other.loads)
        else:
            if path.suffix.lower() not in KRL_SUFFIXES:
                raise InputError(path, "--declarations", "a KRL program takes KUKA's $config.dat (TOOL_DATA...)")
            found_tools, found_objects = _krl_system_data(path)
        if not found_tools and not found_objects and not (program.kind == "rapid" and other.loads):
            raise InputError(path, "--declarations", "declares no tool, work object or load (tooldata, wobjdata, "
                             "loaddata; TOOL_DATA, BASE_DATA)")  # fmt: skip
        for name in [*found_tools, *found_objects]:
            if name.lower() in where:
                raise InputError(path, name, f"declared in {where[name.lower()]} too: which one the controller uses "
                                 "depends on its task and scope; give one file")  # fmt: skip
            where[name.lower()] = path
        tools.update(found_tools)
        objects.update(found_objects)
    files = {name: path.name for name, path in where.items() if path != program.path}
    return replace(program, tools=tools, work_objects=objects, declared_in=files, loads=found_loads)


def _krl_system_data(path: Path) -> tuple[dict[str, ToolData], dict[str, np.ndarray]]:
    """``TOOL_DATA[n]`` (each with ``LOAD_DATA[n]``'s mass and centre of mass where it gives
    one: M -1 is the controller's "no load data"), and ``BASE_DATA[m]``, of a $config.dat."""
    text, _ = _read_text(path)
    frames: dict[str, np.ndarray] = {}
    loads: dict[int, tuple[float, np.ndarray]] = {}
    seen: dict[str, int] = {}
    for number, start in enumerate(_line_starts(text), 1):
        code = _KRL_CODE.match(text, start).group()
        match = _KRL_SYSTEM.match(code)
        if match is None:
            continue
        kind, index, body = match.group(1).upper(), int(match.group(2)), match.group(3)
        name = f"{kind}[{index}]"
        fail = partial(InputError, path, f"line {number}, {name}")
        if name in seen:
            raise fail(f"given twice (first on line {seen[name]}): which one the controller holds is not clear")
        seen[name] = number
        if kind == "LOAD_DATA":
            load = _KRL_LOAD.match(body)
            if load is None:
                raise fail("expected {M mass,CM {X ..,Y ..,Z ..,A ..,B ..,C ..},J {...}} (kg, mm)")
            mass = _krl_real("M", load.group(1), fail)
            cm = _krl_components(load.group(2), 0, len(load.group(2)), 0, fail)
            cog = np.array([_krl_real(k, cm[k][0], fail) if k in cm else 0.0 for k in "XYZ"]) * MM
            if mass > MAX_LOAD_KG or np.abs(cog).max() > MAX_COG_MM * MM:
                raise fail(f"a mass of at most {MAX_LOAD_KG:g} kg and a centre of mass within {MAX_COG_MM:g} mm")
            if mass >= 0:
                loads[index] = (mass, cog)
            continue
        components = _krl_components(body, 0, len(body), 0, fail)
        missing = [key for key in _KRL_POSE_KEYS if key not in components]
        if missing:
            raise fail(f"missing {', '.join(missing)}: a frame needs X, Y, Z, A, B and C (mm, deg)")
        values = {key: _krl_real(key, components[key][0], fail) for key in _KRL_POSE_KEYS}
        frames[name] = se3.pose_from_xyz_rpy(
            np.array([values["X"], values["Y"], values["Z"]]) * MM, np.radians([values["C"], values["B"], values["A"]])
        )
    tools = {}
    for name, frame in frames.items():
        if name.startswith("TOOL_DATA"):
            mass, cog = loads.get(int(name[10:-1]), (0.0, np.zeros(3)))
            tools[name] = ToolData(frame, mass, cog, True)
    return tools, {name: frame for name, frame in frames.items() if name.startswith("BASE_DATA")}


# ---------------------------------------------------------------------------------------------
# Writing


def write_program(
    program: Program, corrected: Mapping[str, tuple[np.ndarray, dict[str, int]]], path: str | Path | None = None
) -> str:
    """The program's text with each named target's pose (4x4, m) and config replaced in place.

    Only the numbers' own characters change (RAPID: position and quaternion, and confdata entries
    whose value changed; KRL: X Y Z A B C, and S or T when changed); everything else is kept byte
    for byte. Nothing is written: ``path`` (default the program's) only names the output in
    messages. A name that is not a target, a pose that is not rigid, a config key the target does
    not have or a non-integer config value is a ValueError (a programming error).
    """
    where = Path(path) if path is not None else program.path
    by_name = {target.name: target for target in program.targets}
    unknown = sorted(set(corrected) - set(by_name))
    if unknown:
        raise ValueError(f"{where}: not targets of the program: {', '.join(unknown)}")
    edits: list[tuple[int, int, str]] = []
    for name, (pose, config) in corrected.items():
        target = by_name[name]
        checked = _checked_pose(pose, f"{where}: {name}")
        if program.kind == "rapid":
            edits += _rapid_edits(program.text, target, checked)
        else:
            edits += _krl_edits(target, checked)
        edits += _config_edits(program.text, target, config, f"{where}: {name}")
    return _apply(program.text, edits)


def _checked_pose(pose: np.ndarray, where: str) -> np.ndarray:
    pose = np.asarray(pose, dtype=float)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise ValueError(f"{where}: a pose is a finite (4, 4) array, got shape {pose.shape}")
    rot = pose[:3, :3]
    if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise ValueError(f"{where}: the pose's rotation is not a rotation matrix")
    return pose


def _apply(text: str, edits: list[tuple[int, int, str]]) -> str:
    """``text`` with each ``[start, end)`` replaced (edits do not overlap)."""
    pieces, at = [], 0
    for start, end, new in sorted(edits):
        pieces += [text[at:start], new]
        at = end
    pieces.append(text[at:])
    return "".join(pieces)


def _fixed(value: float, decimals: int) -> str:
    """``value`` with ``decimals`` decimals, never ``-0.000``."""
    text = f"{value:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def rapid_pose_values(pose: np.ndarray, near: np.ndarray | None = None) -> tuple[list[str], list[str]]:
    """Texts of x y z (mm, 3 decimals) and q1..q4 (w x y z, 9 decimals, unit), the quaternion's sign
    chosen so its dot product with ``near`` (the original quaternion) is positive."""
    q = se3.rotation_quaternion(pose[:3, :3])
    q = q / np.linalg.norm(q)
    if near is not None and float(np.dot(q, near)) < 0:
        q = -q
    return [_fixed(v / MM, 3) for v in pose[:3, 3]], [_fixed(v, 9) for v in q]


def format_rapid_pose(pose: np.ndarray, near: np.ndarray | None = None) -> tuple[str, str]:
    """``("[x,y,z]", "[q1,q2,q3,q4]")`` of a pose (m) in RAPID's units (mm, quaternion w x y z)."""
    trans, quat = rapid_pose_values(pose, near)
    return f"[{','.join(trans)}]", f"[{','.join(quat)}]"


def krl_abc_deg(rot: np.ndarray) -> tuple[float, float, float]:
    """KUKA's A B C (deg) of a rotation, ``R = Rz(A) Ry(B) Rx(C)``; at B = +-90 deg, C = 0."""
    if math.hypot(rot[0, 0], rot[1, 0]) < GIMBAL_LOCK_RAD:
        b = math.pi / 2 if rot[2, 0] < 0 else -math.pi / 2
        return math.degrees(math.atan2(-rot[0, 1], rot[1, 1])), math.degrees(b), 0.0
    roll, pitch, yaw = se3.rpy_from_rotation(rot)
    return math.degrees(yaw), math.degrees(pitch), math.degrees(roll)


def krl_pose_values(pose: np.ndarray) -> dict[str, str]:
    """Texts of X Y Z (mm, 3 decimals) and A B C (deg, 5 decimals) of a pose (m)."""
    values = dict(zip(("X", "Y", "Z"), (_fixed(v / MM, 3) for v in pose[:3, 3]), strict=True))
    values |= dict(zip(("A", "B", "C"), (_fixed(v, 5) for v in krl_abc_deg(pose[:3, :3])), strict=True))
    return values


def format_krl_pose(pose: np.ndarray) -> str:
    """``X ..,Y ..,Z ..,A ..,B ..,C ..`` of a pose (m), in KRL's units (mm, deg)."""
    return ",".join(f"{key} {value}" for key, value in krl_pose_values(pose).items())


def _rapid_edits(text: str, target: ProgramTarget, pose: np.ndarray) -> list[tuple[int, int, str]]:
    near = np.array([float(re.sub(r"\s+", "", text[slice(*target.spans[k])])) for k in ("q1", "q2", "q3", "q4")])
    trans, quat = rapid_pose_values(pose, near)
    return [(*target.spans[key], value) for key, value in zip(_RAPID_POSE_KEYS, trans + quat, strict=True)]


def _krl_edits(target: ProgramTarget, pose: np.ndarray) -> list[tuple[int, int, str]]:
    return [(*target.spans[key], value) for key, value in krl_pose_values(pose).items()]


def _config_edits(
    text: str, target: ProgramTarget, config: Mapping[str, int], where: str
) -> list[tuple[int, int, str]]:
    """Edits of the config values that changed, each written in the style it was read in."""
    unknown = sorted(set(config) - set(target.config))
    if unknown:
        raise ValueError(
            f"{where}: the target has no {', '.join(unknown)} in the file (it has {sorted(target.config)})"
        )
    edits = []
    for key, value in config.items():
        if isinstance(value, bool) or not float(value).is_integer():
            raise ValueError(f"{where}: config {key} = {value!r} is not an integer")
        if int(value) != target.config[key]:
            span = target.spans[key]
            edits.append((*span, _integer_text(text[slice(*span)], int(value), f"{where}: {key}")))
    return edits


def _integer_text(original: str, value: int, where: str) -> str:
    """``value`` as a decimal, or as a ``'B...'``/``'H...'`` literal of at least the original's width."""
    if not original.startswith("'"):
        return str(value)
    if value < 0:
        raise ValueError(f"{where}: {value} cannot be written as {original}")
    letter, width = original[1], len(original) - 3
    digits = format(value, "b" if letter in "Bb" else "X")
    return f"'{letter}{digits.rjust(width, '0')}'"


# ---------------------------------------------------------------------------------------------
# The comment header: what a corrected program assumed (fgcal.data.assumptions)

CORRECTED_MARK = "corrected by fgcal compensate"  # the header's first words: a program corrected already
_FIRST_LINE = {
    "rapid": re.compile(r"[ \t]*MODULE\b", re.IGNORECASE),
    "krl": re.compile(r"[ \t]*DEFDAT\b", re.IGNORECASE),
}
COMMENT = {"rapid": "!", "krl": ";"}


def corrected_at(program: Program) -> int | None:
    """The line of an fgcal header in the program (it was corrected already), else None."""
    mark = re.compile(rf"^[ \t]*{re.escape(COMMENT[program.kind])}[ \t]*{CORRECTED_MARK}", re.MULTILINE)
    found = mark.search(program.text)
    return None if found is None else program.text.count("\n", 0, found.start()) + 1


def with_header(program: Program, text: str, lines: list[str]) -> tuple[str, int]:
    """``text`` (the program's, corrected) with ``lines`` (comments, ASCII) after its MODULE or
    DEFDAT line, where the language has comments (before it, RAPID has none and KRL keeps its
    ``&`` header), in the file's line endings; and how many lines came in (0: no such line)."""
    opening = None
    for match in re.finditer(r"[^\n]*\n", text):
        if _FIRST_LINE[program.kind].match(match.group(0)):
            opening = match
            break
    if opening is None:
        return text, 0
    ending = "\r\n" if opening.group(0).endswith("\r\n") else "\n"
    block = "".join(line + ending for line in lines)
    return text[: opening.end()] + block + text[opening.end() :], len(lines)
