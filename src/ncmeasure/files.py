"""Replacing a file whole: write a new temporary file beside it, then rename it over it.

Every file ncmeasure writes in one piece (``meta.json``, ``results.json``, the
report page and its plots, exports) goes through :func:`replace_text` or
:func:`replace_binary`; :func:`write_whole` writes a finished text or bytes and
turns a failure into one :class:`~ncmeasure.errors.OutputError` naming the
file. The temporary file gets a name nobody can predict and is created
exclusively (``O_CREAT | O_EXCL``, and ``O_NOFOLLOW`` where the system has
it): a file or symlink someone placed beside the target is never followed,
written or replaced, and two writers never share a temporary file.
A reader sees the old file or the new one, whole; a failure removes the
temporary file and leaves the target as it was.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, AnyStr, Final

from ncmeasure.errors import OutputError

__all__ = ["replace_binary", "replace_by_path", "replace_text", "write_whole"]

_FLAGS: Final = (
    os.O_WRONLY
    | os.O_CREAT
    | os.O_EXCL
    | getattr(os, "O_NOFOLLOW", 0)
    | getattr(os, "O_BINARY", 0)  # Windows: no newline translation below Python's own
    | getattr(os, "O_CLOEXEC", 0)
)
_ATTEMPTS: Final = 100


def _create_temporary(target: Path, suffix: str = ".tmp") -> tuple[int, Path]:
    """A new, exclusively created file beside ``target``: its descriptor and path.

    The mode is 0o666 less the umask, as for any new file (not mkstemp's 0o600).
    """
    for _ in range(_ATTEMPTS):
        temporary = target.with_name(f".{target.name}.{secrets.token_hex(6)}{suffix}")
        try:
            return os.open(temporary, _FLAGS, 0o666), temporary
        except FileExistsError:
            continue
    raise FileExistsError(f"{target.parent}: no free temporary name for {target.name}")


@contextlib.contextmanager
def _replace(
    target: Path, opener: Callable[[int], IO[AnyStr]], fsync: bool
) -> Iterator[IO[AnyStr]]:
    fd, temporary = _create_temporary(target)
    try:
        with opener(fd) as file:
            yield file
            file.flush()
            if fsync:
                os.fsync(file.fileno())
        temporary.replace(target)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise


@contextlib.contextmanager
def replace_text(
    path: str | os.PathLike[str],
    *,
    encoding: str = "utf-8",
    newline: str | None = None,
    fsync: bool = False,
) -> Iterator[IO[str]]:
    """Write a text file whole: a new temporary file, renamed over ``path`` at the end.

    Args:
        path: The file to replace (or create).
        encoding: The text encoding.
        newline: As for :func:`open` (``"\\n"`` for the same line ends everywhere).
        fsync: Also fsync the file before the rename (survives a power cut).

    Yields:
        The open temporary file. When the ``with`` block raises, it is removed
        and ``path`` stays as it was.

    Raises:
        OSError: The temporary file cannot be created, written or renamed.
    """

    def opener(fd: int) -> IO[str]:
        return os.fdopen(fd, "w", encoding=encoding, newline=newline)

    with _replace(Path(path), opener, fsync) as file:
        yield file


@contextlib.contextmanager
def replace_binary(path: str | os.PathLike[str], *, fsync: bool = False) -> Iterator[IO[bytes]]:
    """Write a binary file whole; see :func:`replace_text`."""

    def opener(fd: int) -> IO[bytes]:
        return os.fdopen(fd, "wb")

    with _replace(Path(path), opener, fsync) as file:
        yield file


def write_whole(
    path: str | os.PathLike[str],
    data: str | bytes,
    *,
    fsync: bool = False,
    parents: bool = False,
    newline: str | None = None,
) -> Path:
    """Write ``data`` (text as UTF-8, or bytes) to ``path`` whole, and return the path.

    Args:
        path: The file to replace (or create).
        data: Its whole contents.
        fsync: Also fsync the file before the rename (survives a power cut).
        parents: Create its folder (and theirs) when missing.
        newline: For text, as for :func:`open` (``"\\n"`` for the same line ends
            everywhere).

    Raises:
        OutputError: The file (or its folder) cannot be written; the message names
            the file and the system's reason. The file stays as it was.
    """
    target = Path(path)
    try:
        if parents:
            target.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, bytes):
            with replace_binary(target, fsync=fsync) as binary:
                binary.write(data)
        else:
            with replace_text(target, newline=newline, fsync=fsync) as text:
                text.write(data)
    except OSError as exc:
        raise OutputError(f"{target}: cannot be written ({exc.strerror or exc})") from exc
    return target


@contextlib.contextmanager
def replace_by_path(path: str | os.PathLike[str], *, suffix: str = ".tmp") -> Iterator[Path]:
    """For a writer that opens a path itself (asammdf): replace ``path`` whole, likewise.

    Yields the path of an exclusively created, empty temporary file beside ``path``
    (ending in ``suffix``, for writers that go by the ending); it is renamed over
    ``path`` when the block ends, and removed when the block raises.
    """
    target = Path(path)
    fd, temporary = _create_temporary(target, suffix)
    os.close(fd)
    try:
        yield temporary
        temporary.replace(target)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise
