"""The ``ncmeasure`` command's entry point, also ``python -m ncmeasure``.

``ncmeasure --version`` answers here, before the command line (typer, click) is
imported: a script asking for the version should not wait for it.
"""

from __future__ import annotations

import sys


def main() -> None:
    """Entry point of the console script."""
    if sys.argv[1:] == ["--version"]:
        from ncmeasure._version import __version__

        sys.stdout.write(f"ncmeasure {__version__}\n")
        return
    from ncmeasure.cli import main as cli_main

    cli_main()


if __name__ == "__main__":
    main()
