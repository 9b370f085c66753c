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
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ncmeasure.errors import ConfigError, NcMeasureError

__all__ = [
    "MAX_TOML_BYTES",
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
