"""``python -m ncmeasure``: the same as the ``ncmeasure`` command."""

from ncmeasure.cli import main

main()
