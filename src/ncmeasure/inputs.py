"""Reading what a user hands ncmeasure: regular files of bounded size, TOML and JSON.

Every file ncmeasure reads from a user's folders (machine files, controller
definitions, column, object and register maps, templates, ``schedule.json``,
program files) goes through :func:`read_text`, and every TOML or JSON text
through :func:`parse_toml` or :func:`parse_json`. A FIFO, a device such as
``/dev/zero``, a file of gigabytes, an integer of 5000 digits or brackets
nested a thousand deep then become one message that names the file (and the
line where it can), never a hang, a full memory or a traceback.
"""

from __future__ import annotations

import json
import os
import re
import stat
import sys
import tomllib
from collections.abc import Callable, Collection, Iterable
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from ncmeasure.errors import ConfigError, NcMeasureError

__all__ = [
    "MAX_TOML_BYTES",
    "format_validation_error",
    "parse_json",
    "parse_toml",
    "plain_file_name",
    "read_bytes",
    "read_text",
]

MAX_TOML_BYTES = 1024 * 1024
"""Largest machine file, controller definition or map (1 MiB; a 32-axis machine file
with every comment is a few dozen kB)."""

_CHUNK = 64 * 1024
_UNSAFE_NAME = re.compile(r"[/\\\x00-\x1f\x7f]")


def plain_file_name(name: str) -> bool:
    """True for a file name that stays inside its folder.

    Not empty, no path separator (``/`` or ``\\``) or control character, and not
    starting with a dot (``.``, ``..`` and hidden files such as ncmeasure's own
    staging folders).
    """
    return bool(name) and not name.startswith(".") and not _UNSAFE_NAME.search(name)


def _size_text(size: int) -> str:
    if size >= 1024 * 1024:
        return f"{size / (1024 * 1024):.0f} MiB"
    return f"{size / 1024:.0f} kiB" if size >= 1024 else f"{size} bytes"


def read_bytes(
    path: str | Path,
    what: str,
    max_bytes: int,
    error: type[NcMeasureError] = ConfigError,
    missing: str | None = None,
) -> bytes:
    """The bytes of a regular file of at most ``max_bytes``.

    The file is opened without waiting (a FIFO cannot block) and refused unless it
    is a regular file; it is read in chunks up to the limit, so a file that grows
    while it is read is refused too.

    Args:
        path: The file (symbolic links are followed).
        what: What the file should be, for messages (``a machine file``).
        max_bytes: The largest size accepted.
        error: The exception raised for every problem.
        missing: Message for a file that does not exist (default ``PATH: no such file``).

    Raises:
        error: missing, a folder, not a regular file, larger than ``max_bytes``, unreadable.
    """
    path = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError as exc:
        raise error(missing or f"{path}: no such file") from exc
    except IsADirectoryError as exc:
        raise error(f"{path}: is a directory, expected {what}") from exc
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise error(f"{path}: is a directory, expected {what}")
        if not stat.S_ISREG(info.st_mode):
            raise error(f"{path}: not a regular file (a device, pipe or socket), expected {what}")
        limit = f"more than the {_size_text(max_bytes)} {what} may have"
        if info.st_size > max_bytes:
            raise error(f"{path}: {_size_text(info.st_size)}, {limit}")
        chunks: list[bytes] = []
        total = 0
        want = info.st_size + 1  # the whole file and its end at once, if it does not grow
        while True:
            chunk = os.read(fd, min(want, max_bytes + 1 - total))
            want = _CHUNK
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > max_bytes:
                raise error(f"{path}: grows beyond {_size_text(max_bytes)} while read, {limit}")
        return b"".join(chunks)
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    finally:
        os.close(fd)


def read_text(
    path: str | Path,
    what: str,
    max_bytes: int,
    error: type[NcMeasureError] = ConfigError,
    missing: str | None = None,
) -> str:
    """The UTF-8 text of a regular file of at most ``max_bytes`` (see :func:`read_bytes`).

    Raises:
        error: as :func:`read_bytes`, or the file is not UTF-8 text.
    """
    data = read_bytes(path, what, max_bytes, error, missing)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(f"{path}:{line}: not UTF-8 text, expected {what}") from exc


_MAX_DIGITS = sys.get_int_max_str_digits() or 4300
# An integer Python refuses to convert: more digits than the limit (TOML allows '_').
_LONG_INTEGER = re.compile(rf"\d(?:_?\d){{{_MAX_DIGITS},}}")
# What nests, and what hides brackets from the count: strings and comments (TOML's rules,
# which cover JSON's strings too).
_NESTING_TOKENS = re.compile(
    r'"""(?:[^\\]|\\.)*?"""|\'\'\'.*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*|[\[\]{}]',
    re.S,
)
MAX_NESTING = 64
"""Deepest nesting of arrays and tables a message points at (none of ncmeasure's files
nests more than a few levels)."""


def _line(text: str, index: int) -> int:
    return text.count("\n", 0, index) + 1


def _too_deep_line(text: str) -> int | None:
    """The line where arrays or tables first nest deeper than :data:`MAX_NESTING`."""
    depth = 0
    for token in _NESTING_TOKENS.finditer(text):
        bracket = token.group()
        if bracket in "[{":
            depth += 1
            if depth > MAX_NESTING:
                return _line(text, token.start())
        elif bracket in "]}":
            depth = max(depth - 1, 0)
    return None


def _too_long_integer(text: str) -> str:
    match = _LONG_INTEGER.search(text)
    where = f" (at line {_line(text, match.start())})" if match else ""
    return f"an integer of more than {_MAX_DIGITS} digits{where}"


def _too_deep(text: str) -> str:
    line = _too_deep_line(text)
    return "arrays or tables nested too deep" + (f" (at line {line})" if line else "")


def _parse(
    loads: Callable[[str], Any],
    syntax_error: type[ValueError],
    kind: str,
    text: str,
    where: str,
    error: type[NcMeasureError],
) -> Any:
    try:
        return loads(text)
    except syntax_error as exc:
        raise error(f"{where}: invalid {kind}: {exc}") from exc
    except ValueError as exc:
        raise error(f"{where}: invalid {kind}: {_too_long_integer(text)}") from exc
    except RecursionError as exc:
        raise error(f"{where}: invalid {kind}: {_too_deep(text)}") from exc


def parse_toml(text: str, where: str, error: type[NcMeasureError] = ConfigError) -> dict[str, Any]:
    """The tables of a TOML text, or ``error`` naming ``where`` and the line.

    Raises:
        error: invalid TOML, an integer Python cannot convert, or nesting deeper than
            Python's recursion allows.
    """
    tables: dict[str, Any] = _parse(
        tomllib.loads, tomllib.TOMLDecodeError, "TOML", text, where, error
    )
    return tables


def parse_json(text: str, where: str, error: type[NcMeasureError]) -> Any:
    """The value of a JSON text, or ``error`` naming ``where`` and the line.

    Raises:
        error: invalid JSON, an integer Python cannot convert, or nesting deeper than
            Python's recursion allows.
    """
    return _parse(json.loads, json.JSONDecodeError, "JSON", text, where, error)


_BRANCH_TAGS = {"int", "float", "bool", "str", "list", "tuple", "dict", "none"}
"""Names pydantic gives the branches of a union in an error's location."""
_TYPE_ERRORS = {
    "int_type": "an integer",
    "float_type": "a number",
    "bool_type": "true/false",
    "string_type": "text in quotes",
    "tuple_type": "a list",
    "list_type": "a list",
    "dict_type": "a table",
}


def _shown(value: Any) -> str:
    if isinstance(value, str):
        return f"the text {value!r}"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | tuple | dict):
        return "a list" if not isinstance(value, dict) else "a table"
    return repr(value)


def _loc_text(loc: Iterable[int | str], tables: Collection[str] = ()) -> str:
    text = ""
    previous: int | str | None = None
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        elif isinstance(previous, str) and previous in tables:
            # a key the user chose (X_current_a), not a field name: kept as written
            text += f".{part}" if re.fullmatch(r"\w+", part) else f"[{part!r}]"
        elif re.fullmatch(r"[a-z_][a-z0-9_]*", part) and part not in _BRANCH_TAGS:
            text += f".{part}" if text else part
        # union branch tags such as 'list[float]' or 'function-after[...]' add nothing
        previous = part
    return text or "(file)"


def format_validation_error(
    exc: ValidationError,
    prefix: str = "",
    schema_hint: str = "",
    tables: Collection[str] = (),
) -> list[str]:
    """Turn a pydantic error into ``location: message`` lines, one per problem.

    Args:
        exc: The validation error.
        prefix: Location the error's locations are relative to (``link``).
        schema_hint: Where the valid keys are listed, added to unknown-key messages.
        tables: Fields that are tables keyed by names the user chose (such as
            channel names); their keys stay in the location as written.
    """
    lines: list[str] = []
    seen: set[str] = set()
    expected_at: dict[str, int] = {}  # a place's "expected ..." line: union branches join it
    judged: set[str] = set()  # places with a message other than "expected ..."
    for error in exc.errors(include_url=False):
        loc = _loc_text(error["loc"], tables)
        if error["type"] == "extra_forbidden" and error["loc"]:
            # the last part is the user's own key, kept as written (Park_mm, park-mm)
            parent, key = error["loc"][:-1], str(error["loc"][-1])
            loc = _loc_text(parent, tables) if parent else ""
            shown = f".{key}" if re.fullmatch(r"\w+", key) else f"[{key!r}]"
            loc = (loc + shown).lstrip(".") if loc != "(file)" else shown.lstrip(".")
        if prefix:
            loc = prefix if loc == "(file)" else f"{prefix}.{loc}"
        message = error["msg"]
        if error["type"] == "extra_forbidden":
            message = "unknown key (check the spelling" + (
                f"; see {schema_hint})" if schema_hint else ")"
            )
        elif error["type"] == "missing":
            message = "required key is missing"
        elif error["type"] in _TYPE_ERRORS:
            # strict types: "40" is no number and "no" no boolean; say what was given
            message = f"expected {_TYPE_ERRORS[error['type']]}, got {_shown(error['input'])}"
        expected = message.startswith("expected ")
        if expected and loc in expected_at:  # a union's branches: one line per place
            number = expected_at[loc]
            joined = f"{lines[number].split(', got ')[0]} or {message.removeprefix('expected ')}"
            seen.discard(lines[number])
            lines[number] = joined
            seen.add(joined)
            continue
        line = f"{loc}: {message}"
        if line in seen:
            continue
        if expected:
            expected_at[loc] = len(lines)
        else:
            judged.add(loc)
        lines.append(line)
        seen.add(line)
    # A union whose branch of the right type judged the value (100000 for an integer up
    # to 99999, or true/false): the other branches' "expected ..." says nothing more.
    dropped = {expected_at[loc] for loc in judged if loc in expected_at}
    return [line for number, line in enumerate(lines) if number not in dropped]
