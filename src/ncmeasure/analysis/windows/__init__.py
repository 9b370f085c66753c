"""Finding the windows of constant velocity, from a recording read in passes of chunks.

The whole-signal statistics (:mod:`~ncmeasure.analysis.windows.scan`, exact by
:mod:`~ncmeasure.analysis.windows.streaming`), the pass over the rows that finds
the stretches each way of finding windows looks at
(:mod:`~ncmeasure.analysis.windows.sweep`), and the finder that trims, checks and
labels them (:mod:`~ncmeasure.analysis.windows.finder`,
:mod:`~ncmeasure.analysis.windows.chunked`). A recording in memory is read the same
way, as one chunk.
"""
