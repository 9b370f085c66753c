"""The ``ncmeasure`` command's entry point, also ``python -m ncmeasure``.

``ncmeasure --version`` answers here, before the command line (typer, click) is
imported: a script asking for the version should not wait for it.

OpenBLAS works with one thread unless ``OPENBLAS_NUM_THREADS`` says otherwise
(set here, before numpy is first imported): the analysis' matrices are small,
and on a busy two-core computer a second BLAS thread spins for CPU it does not
get (the position dependency's pseudo-inverse took 35 times the CPU of one
thread). The results are the same (``docs/performance.md``).
"""

from __future__ import annotations

import os
import sys


def main() -> None:
    """Entry point of the console script."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if sys.argv[1:] == ["--version"]:
        from ncmeasure._version import __version__

        sys.stdout.write(f"ncmeasure {__version__}\n")
        return
    from ncmeasure.cli import main as cli_main

    cli_main()


if __name__ == "__main__":
    main()
