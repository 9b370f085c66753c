"""Offline friction analysis: windows -> friction table -> fits -> diagnosis -> results.json.

Pure numpy/scipy on a recording read in passes of chunks (its file, or a
:class:`~ncmeasure.recording.Recording` in memory as one chunk); nothing here
talks to a drive.

- ``analyze.py``: the orchestrator, :func:`~ncmeasure.analysis.analyze.analyze`;
- ``reading.py``: the passes over a recording shared by all its axes;
- ``axis.py``: one axis' facts, checks, and its result from its windows;
- ``windows/``: the windows of constant velocity (statistics, sweep, finder,
  labels by schedule or clusters, the work that rides along the readings);
- ``friction/``: the friction table and the models fitted to it;
- ``judgement/``: diagnosis along the travel, verdicts, summaries,
  comparisons of runs and fleets.
"""
