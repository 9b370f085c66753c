"""The files ncmeasure writes and reads, as pydantic models: the bottom of the package.

Every stage speaks through these files, so their models sit below every stage
(the planner, the recorder, the analysis, the store, the dashboard) and import
nothing of them:

- :mod:`.header`       the three keys every file starts with, and the one way to read a file
- :mod:`.axis`         what a feed axis is, mechanically (embedded by the machine file too)
- :mod:`.schedule`     ``schedule.json``: what the generated programs do and when
- :mod:`.recording`    a recording's ``meta.json`` and ``events.jsonl``
- :mod:`.results`      ``results.json``: the analysis of one recording
- :mod:`.comparison`   a comparison of results, and the limits that judge it
- :mod:`.dryrun`       ``dryrun.json``: how far a dry run on the virtual machine went

``ncmeasure schema machine|schedule|results`` prints their JSON Schemas.
"""
