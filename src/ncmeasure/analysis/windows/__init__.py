"""Finding the windows of constant velocity, from a recording read in passes of chunks.

- ``settings.py``, ``model.py``: the settings, and the windows, clusters and
  segmentations found;
- ``streaming.py``, ``scan.py``: whole-signal statistics, exact, chunk by chunk;
- ``sweep.py``, ``chunked.py``: the passes over the rows that find the
  stretches of each way (marker, command, plateaus), and the slices kept of them;
- ``detection.py``, ``signals.py``, ``finder.py``: what the signals resolve,
  vectorised helpers, and the finder that trims, checks and labels the windows
  (``schedule.py`` by the schedule, ``clusters.py`` without one);
- ``find.py``: the windows of given arrays or of a recording in memory;
- ``watch.py``: work on the raw rows that rides along the analysis' readings.
"""
