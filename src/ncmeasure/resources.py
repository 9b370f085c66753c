"""Where the built-in controller definitions and templates live.

In an installed wheel they are package data under ``ncmeasure/_data``; in a
source checkout they are the top-level ``controllers/`` and ``templates/``
folders. User folders given on the command line are searched first.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["builtin_dir"]


def builtin_dir(kind: str) -> Path:
    """The built-in ``controllers`` or ``templates`` folder."""
    packaged = Path(str(resources.files("ncmeasure"))) / "_data" / kind
    if packaged.is_dir():
        return packaged
    # Source checkout (editable install or tests run against src/).
    return Path(__file__).resolve().parents[2] / kind
