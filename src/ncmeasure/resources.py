"""Where the built-in controller definitions and templates live.

In an installed wheel they are package data under ``ncmeasure/_data``; in a
source checkout they are the top-level ``controllers/`` and ``templates/``
folders. User folders given on the command line are searched first.
"""

from __future__ import annotations

from collections.abc import Iterable
from importlib import resources
from pathlib import Path

__all__ = ["available_dialects", "builtin_dir"]


def builtin_dir(kind: str) -> Path:
    """The built-in ``controllers`` or ``templates`` folder."""
    packaged = Path(str(resources.files("ncmeasure"))) / "_data" / kind
    if packaged.is_dir():
        return packaged
    # Source checkout (editable install or tests run against src/).
    return Path(__file__).resolve().parents[2] / kind


def available_dialects(user_dirs: Iterable[Path] = ()) -> dict[str, Path]:
    """Dialect names and their files; user folders hide built-ins of the same name.

    Here, not beside the dialect's models: finding the files needs no pydantic
    (``ncmeasure init`` names a built-in dialect without loading it).
    """
    found: dict[str, Path] = {}
    for folder in reversed([*user_dirs, builtin_dir("controllers")]):
        if folder.is_dir():
            for path in sorted(folder.glob("*.toml")):
                found[path.stem] = path
    return dict(sorted(found.items()))
