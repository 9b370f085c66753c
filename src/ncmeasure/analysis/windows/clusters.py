"""Rapids dropped, and without a schedule, windows clustered into steps and positions.

Rapid traverse is dropped first: windows faster than ``max_velocity_mm_min``
(or the schedule's top step, or the machine's rapid traverse velocity).
Without a schedule, the fastest level when it holds ``rapid_count_factor``
times more windows than a typical level, and windows lasting
``duration_outlier_factor`` times longer than their level's trend of duration
over velocity, where their level holds a window too many or stands alone
(warm-up strokes over the whole travel). Then velocities are
clustered into steps (gaps in |v| larger than ``step_tolerance`` relative,
``step_floor_mm_min`` absolute, :data:`STEP_QUANTA` counts of the velocity)
and window centres into positions (gaps
larger than ``position_gap_mm`` or ``position_gap_fraction`` of the span,
found among the slower half of the steps, whose windows no planner shifts;
every window then joins the nearest position).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from ncmeasure.analysis.windows.detection import Detection
from ncmeasure.analysis.windows.model import (
    Candidate,
    Cluster,
    VelocityWindow,
    labelled_window,
    nan_mean,
)
from ncmeasure.analysis.windows.settings import (
    STEP_QUANTA,
    THIN_STEP_SHARE,
    SegmentSettings,
    WindowSource,
)
from ncmeasure.analysis.windows.signals import cluster_gaps, clusters_of
from ncmeasure.formats.schedule import AxisSummary

__all__ = ["drop_rapids", "drop_thin_steps", "drop_too_fast", "label_by_clusters", "levels"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]


def drop_too_fast(
    candidates: list[Candidate],
    detection: Detection,
    summary: AxisSummary | None,
    rapid_mm_min: float | None,
) -> list[Candidate]:
    """Drop what is faster than the top step (settings, else schedule) or at the rapid velocity.

    ``detection``'s warnings say how many were dropped.
    """
    top = detection.settings.max_velocity_mm_min
    if top is None and summary is not None and summary.velocities_mm_min:
        top = max(summary.velocities_mm_min)
    if top is None and rapid_mm_min is not None:
        # At the machine's rapid traverse velocity a move is a rapid, not a measurement.
        rapid = rapid_mm_min
        kept = [c for c in candidates if abs(c.level_mm_min) < rapid - float(detection.band(rapid))]
        if len(kept) < len(candidates):
            detection.warnings.append(
                f"{len(candidates) - len(kept)} windows at the rapid traverse velocity "
                f"({rapid:g} mm/min, machine file): dropped"
            )
        return kept
    if top is None:
        return candidates
    limit = top + float(detection.band(top))
    kept = [c for c in candidates if abs(c.level_mm_min) <= limit]
    if len(kept) < len(candidates):
        detection.warnings.append(
            f"{len(candidates) - len(kept)} windows faster than {top:g} mm/min "
            "(rapid traverse): dropped"
        )
    return kept


def levels(
    candidates: Sequence[Candidate], settings: SegmentSettings, quantum_mm_min: float = 0.0
) -> IntArray:
    """The velocity level (step) of every candidate, 0 for the slowest.

    Levels closer than ``step_tolerance`` (relative), ``step_floor_mm_min``, or
    :data:`STEP_QUANTA` counts of the velocity signal (``quantum_mm_min``) are one
    step: the median of readings in counts sits on one count or the next.
    """
    speeds = np.abs(np.array([c.level_mm_min for c in candidates]))
    gaps = np.maximum(settings.step_tolerance * speeds, settings.step_floor_mm_min)
    gaps = np.maximum(gaps, STEP_QUANTA * quantum_mm_min)
    return cluster_gaps(speeds, gaps)


def _quantum(detection: Detection) -> float:
    """The count that groups the steps: the readings' own, unless the position measures."""
    return 0.0 if detection.from_position else detection.v_quantum


def drop_rapids(candidates: list[Candidate], detection: Detection) -> list[Candidate]:
    """Without a schedule: drop the rapid-traverse level and over-long windows."""
    settings = detection.settings
    if len(candidates) < 3:
        return candidates
    labels = levels(candidates, settings, _quantum(detection))
    count = int(labels.max()) + 1
    per_level = np.bincount(labels, minlength=count)
    if count >= 3:
        fastest = count - 1
        typical = float(np.median(per_level[:-1]))
        if per_level[fastest] > settings.rapid_count_factor * max(typical, 1.0):
            speed = float(
                np.median(
                    [
                        abs(c.level_mm_min)
                        for c, k in zip(candidates, labels, strict=True)
                        if k == fastest
                    ]
                )
            )
            detection.warnings.append(
                f"the fastest level, {speed:g} mm/min, holds {per_level[fastest]} windows "
                f"where the others hold about {typical:g}: taken as rapid traverse, dropped"
            )
            candidates = [c for c, k in zip(candidates, labels, strict=True) if k != fastest]
            labels = levels(candidates, settings, _quantum(detection))
            count = int(labels.max()) + 1
    speeds = np.abs(np.array([c.level_mm_min for c in candidates]))
    durations = np.array([(c.stop - c.start) * detection.dt for c in candidates])
    log_d = np.log(durations)
    level_v = np.array([np.median(np.log(speeds[labels == k])) for k in range(count)])
    level_d = np.array([np.median(log_d[labels == k]) for k in range(count)])
    if count >= 3:
        from scipy.stats import theilslopes  # only here: scipy.stats takes a second to import

        slope, intercept, _, _ = theilslopes(level_d, level_v)
        expected = intercept + slope * np.log(speeds)
    else:
        expected = level_d[labels]
    long = log_d - expected > math.log(settings.duration_outlier_factor)
    # A warm-up stroke or traverse is a window too many at its level, or alone at a
    # level of its own; a long window where its level holds as many as a typical
    # one is a clean run whose neighbours came out short.
    per_level = np.bincount(labels, minlength=count)
    long &= per_level[labels] != np.median(per_level)
    if long.any():
        detection.warnings.append(
            f"{int(long.sum())} windows last over {settings.duration_outlier_factor:g} times "
            "longer than the others at their velocity (warm-up strokes, traverses): dropped"
        )
        candidates = [c for c, bad in zip(candidates, long, strict=True) if not bad]
    return candidates


THIN_STEP_NEAR = 0.05
"""A thin step within this share of a neighbour's level can be a piece of that neighbour's run."""

THIN_STEP_OVERSHOOT = 0.25
"""The fastest thin step can be an overshoot of the next one only within this share above it:
the time at a speed falls as 1/speed, so a real fastest speed far above the next holds few
samples (ten times the next speed, a tenth of its samples)."""


def drop_thin_steps(candidates: list[Candidate], detection: Detection) -> list[Candidate]:
    """Without a command or a schedule: drop the steps that only a fragment of a run backs.

    A step whose windows hold fewer than :data:`THIN_STEP_SHARE` of the samples of
    each step next to it (the one it has, at the ends) is no speed of its own but a
    piece of a run where the readings happened to hold another level (a "215 mm/min"
    step of 4 samples where nothing ran above 200, a 492 beside 500 samples at 499):
    its windows are dropped, and counted in ``detection``'s warnings. Only a step within
    :data:`THIN_STEP_NEAR` of a neighbour's level, or the fastest one within
    :data:`THIN_STEP_OVERSHOOT` above the next (an overshoot), can be such a piece: a
    short step far from the others (the slowest speed of a short program, a fastest
    speed ten times the next) is a speed of its own.
    """
    if len(candidates) < 2:
        return candidates
    labels = levels(candidates, detection.settings, _quantum(detection))
    count = int(labels.max()) + 1
    if count < 2:
        return candidates
    samples = np.bincount(labels, weights=[c.stop - c.start for c in candidates], minlength=count)
    speeds = np.abs(np.array([c.level_mm_min for c in candidates]))
    level = np.array([float(np.median(speeds[labels == k])) for k in range(count)])
    thin = np.zeros(count, dtype=np.bool_)
    for k in range(count):
        nearby = [j for j in (k - 1, k + 1) if 0 <= j < count]
        # a fragment lies next to the run it broke from (within THIN_STEP_NEAR of its
        # level), or just above the fastest run (an overshoot); a short step far from
        # the others is a step (the time at a speed falls as 1/speed)
        close = any(abs(level[k] - level[j]) <= THIN_STEP_NEAR * level[j] for j in nearby)
        overshoot = k == count - 1 and level[k] <= (1.0 + THIN_STEP_OVERSHOOT) * level[k - 1]
        thin[k] = (close or overshoot) and samples[k] < THIN_STEP_SHARE * min(
            samples[j] for j in nearby
        )
    if not thin.any():
        return candidates
    dropped = [c for c, k in zip(candidates, labels, strict=True) if thin[k]]
    speeds = sorted({round(abs(c.level_mm_min), 3) for c in dropped})
    detection.warnings.append(
        f"{len(dropped)} windows at {', '.join(f'{s:g}' for s in speeds)} mm/min dropped: "
        "together they hold fewer than an eighth of the samples of the velocity "
        "steps next to them (a piece of a run where the readings held another level, "
        "no speed of its own)"
    )
    return [c for c, k in zip(candidates, labels, strict=True) if not thin[k]]


def label_by_clusters(
    candidates: Sequence[Candidate],
    x: FloatArray,
    source: WindowSource,
    detection: Detection,
    *,
    one_position: bool = False,
) -> tuple[list[VelocityWindow], list[Cluster], list[Cluster]]:
    """The windows labelled by the velocity steps and the positions found among them.

    ``one_position``: the windows' positions cannot be compared (integrated from the
    velocity in segments between holes of the time axis): every window is position 0,
    at the median of their positions in their own segments.
    """
    settings = detection.settings
    speeds = np.abs(np.array([c.level_mm_min for c in candidates]))
    step_of = levels(candidates, settings, _quantum(detection))
    steps = clusters_of(speeds, step_of)
    centres = np.array([nan_mean(x[c.start : c.stop]) for c in candidates])
    # Anchor the positions on the slower half of the steps: planners shift the
    # windows of fast steps inward where the run-up would not fit.
    slow = step_of <= (len(steps) - 1) // 2
    anchor = centres[slow & np.isfinite(centres)]
    if len(anchor) == 0:
        anchor = centres[np.isfinite(centres)]
    span = float(anchor.max() - anchor.min()) if len(anchor) else 0.0
    gap = max(settings.position_gap_mm, settings.position_gap_fraction * span)
    if one_position:
        gap = math.inf
    anchor_of = cluster_gaps(anchor, gap)
    anchors = clusters_of(anchor, anchor_of)
    anchor_x = np.array([a.centre for a in anchors])
    position_of = np.argmin(np.abs(centres[:, None] - anchor_x[None, :]), axis=1)
    position_of[~np.isfinite(centres)] = 0
    # Renumber: a position that no window ended up nearest to is left out.
    used = np.unique(position_of)
    position_of = np.searchsorted(used, position_of)
    positions = [
        Cluster(
            index,
            anchors[int(anchor)].centre,
            float(centres[position_of == index].min()),
            float(centres[position_of == index].max()),
            int((position_of == index).sum()),
        )
        for index, anchor in enumerate(used)
    ]
    windows = []
    for candidate, step, position in zip(candidates, step_of, position_of, strict=True):
        sign = 1.0 if candidate.level_mm_min > 0 else -1.0
        windows.append(
            labelled_window(
                detection.axis,
                candidate,
                x,
                source,
                velocity_mm_min=sign * steps[int(step)].centre,
                position_index=int(position),
                step=int(step),
            )
        )
    return windows, steps, positions
