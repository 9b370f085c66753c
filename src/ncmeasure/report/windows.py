"""The analysis windows as times, for shading them in the raw data.

:func:`window_times` turns the analysis' windows (sample ranges) into
(t_start, t_end) pairs. :func:`find_window_times` finds them again in a
recording with the settings stored in ``results.json``, for a report whose
caller did not keep the windows of the analysis.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Mapping

from pydantic import ValidationError

from ncmeasure.analysis.analyze import AnalysisSettings
from ncmeasure.analysis.windows.find import windows_of
from ncmeasure.analysis.windows.model import VelocityWindow
from ncmeasure.recording import Recording

__all__ = ["find_window_times", "window_times"]

log = logging.getLogger(__name__)


def window_times(
    recording: Recording, windows: Iterable[VelocityWindow]
) -> list[tuple[float, float]]:
    """(time of the first sample, time of the last sample) of every window, in seconds."""
    time_s = recording.time_s
    return [
        (float(time_s[w.start]), float(time_s[w.stop - 1]))
        for w in windows
        if 0 <= w.start < w.stop <= len(time_s)
    ]


def find_window_times(
    recording: Recording, axis: str, settings: Mapping[str, object] | None = None
) -> list[tuple[float, float]]:
    """Find the constant-velocity windows of an axis as the analysis does, without a schedule.

    Args:
        recording: The recording.
        axis: The axis.
        settings: ``results.settings``; the analysis defaults where they do not
            parse as :class:`~ncmeasure.analysis.analyze.AnalysisSettings`.

    Raises:
        RecordingError: The axis has no velocity channel or no window is found.
    """
    try:
        segment = AnalysisSettings.model_validate(dict(settings or {}))
    except ValidationError as exc:
        log.debug("results settings do not parse (%s): default window settings", exc)
        segment = AnalysisSettings()
    return window_times(recording, windows_of(recording, axis, settings=segment).windows)
