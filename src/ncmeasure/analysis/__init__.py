"""Offline friction analysis: windows -> friction table -> fits -> diagnosis -> results.json.

Pure numpy/scipy on a :class:`~ncmeasure.recording.Recording`; nothing here
talks to a drive.
"""
