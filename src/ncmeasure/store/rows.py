"""One results.json as the store's rows (pure: no database here).

The characteristics kept per axis are those the report's headline shows
(:func:`ncmeasure.analysis.judgement.summary.axis_headline`): the mean Coulomb friction over
the positions (and per direction), the mean viscous friction per m/min, the
spread along the travel with its signature, and the offset.
"""

from __future__ import annotations

import hashlib
import json
import math
import zlib
from dataclasses import dataclass, field
from typing import Any

from ncmeasure.analysis.judgement.status import CHARACTERISTICS, Characteristic
from ncmeasure.analysis.judgement.summary import axis_headline
from ncmeasure.formats.results import AxisResult, LinearFit, NonlinearFit, Results

__all__ = [
    "CHARACTERISTICS",
    "POINT_COLUMNS",
    "AxisRows",
    "Characteristic",
    "canonical_json",
    "compress",
    "decompress",
    "results_digest",
    "rows_of_axis",
]


def canonical_json(results: Results) -> bytes:
    """The results as compact JSON with sorted keys: the same results, the same bytes."""
    data = results.model_dump(mode="json")
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def results_digest(canonical: bytes) -> str:
    """SHA-256 of the canonical JSON: the identity of a stored measurement."""
    return hashlib.sha256(canonical).hexdigest()


def compress(canonical: bytes) -> bytes:
    """The stored form of the results: zlib at its fastest level (the JSON shrinks three- to
    tenfold; level 6 saves another fifth of the bytes at three times the time, which
    bounded the rate of adding)."""
    return zlib.compress(canonical, 1)


def decompress(stored: bytes) -> Results:
    """The results back from :func:`compress`'s bytes."""
    return Results.model_validate_json(zlib.decompress(stored))


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


POINT_COLUMNS = (
    "position_index",
    "position_mm",
    "direction",
    "velocity_mm_min",
    "median",
    "stderr",
    "mean",
    "std",
    "n",
)
"""The columns of :attr:`AxisRows.points`' tuples, in their order."""


@dataclass
class AxisRows:
    """The rows of one axis of one measurement (ids are filled in by the store)."""

    axis: dict[str, Any]
    points: list[tuple[Any, ...]] = field(default_factory=list)
    """One tuple per point, values in the order of :data:`POINT_COLUMNS` (hundreds per axis:
    tuples, not dicts)."""
    fits: list[tuple[dict[str, Any], list[dict[str, Any]]]] = field(default_factory=list)
    causes: list[dict[str, Any]] = field(default_factory=list)


def _linear_rows(fit: LinearFit, chosen: bool) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    row = {
        "model": "linear",
        "chosen": chosen,
        "accepted": fit.accepted,
        "chi2_reduced": _finite(fit.chi2_reduced),
        "reason": fit.reason,
    }
    parameters = [
        {"name": "coulomb", "value": _finite(fit.coulomb), "stderr": _finite(fit.coulomb_stderr)},
        {
            "name": "viscous_per_mm_min",
            "value": _finite(fit.viscous_per_mm_min),
            "stderr": _finite(fit.viscous_stderr),
        },
    ]
    return row, [{**p, "ci95_low": None, "ci95_high": None} for p in parameters]


def _nonlinear_rows(fit: NonlinearFit, chosen: bool) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    row = {
        "model": fit.model,
        "chosen": chosen,
        "accepted": fit.identifiable,
        "chi2_reduced": _finite(fit.chi2_reduced),
        "reason": fit.reason,
    }
    parameters = []
    for name, value in (fit.parameters or {}).items():
        low, high = (fit.ci95 or {}).get(name, (None, None))
        parameters.append(
            {
                "name": name,
                "value": _finite(value),
                "stderr": None,
                "ci95_low": _finite(low),
                "ci95_high": _finite(high),
            }
        )
    return row, parameters


def rows_of_axis(name: str, result: AxisResult) -> AxisRows:
    """The store's rows of one analysed axis."""
    headline = axis_headline(result)
    per_direction: dict[str, list[float]] = {"positive": [], "negative": []}
    rows = AxisRows(axis={})
    for position in result.positions:
        for direction, found in position.directions.items():
            if found is None:
                continue
            where = {
                "position_index": position.position_index,
                "position_mm": position.position_mm,
                "direction": direction,
            }
            index, mm = position.position_index, position.position_mm
            rows.points += [
                (
                    index,
                    mm,
                    direction,
                    point.velocity_mm_min,
                    point.median,
                    _finite(point.stderr),
                    point.mean,
                    point.std,
                    point.n,
                )
                for point in found.points
            ]
            if found.fit is not None:
                rows.fits.append(_add(where, _linear_rows(found.fit, found.model == "linear")))
                coulomb = _finite(found.fit.coulomb)
                if coulomb is not None:
                    per_direction[direction].append(coulomb)
            for nonlinear in (found.stribeck, found.extended):
                if nonlinear is not None:
                    chosen = found.model == nonlinear.model
                    rows.fits.append(_add(where, _nonlinear_rows(nonlinear, chosen)))
    dependency = result.position_dependency
    for rank, cause in enumerate(dependency.causes if dependency else [], start=1):
        rows.causes.append(
            {"rank": rank, "cause": cause.cause, "score": cause.score, "evidence": cause.evidence}
        )
    rows.axis = {
        "axis": name,
        "verdict": result.verdict.level,
        "verdict_reason": result.verdict.reason,
        "verdict_action": result.verdict.action,
        "quantity": result.quantity,
        "unit": result.unit,
        "windows": result.windows,
        "samples_used": result.samples_used,
        "coulomb": _finite(headline.coulomb),
        "coulomb_positive": _mean(per_direction["positive"]),
        "coulomb_negative": _mean(per_direction["negative"]),
        "viscous_per_m_min": _finite(headline.viscous_per_m_min),
        "spread_percent": _finite(headline.spread_percent),
        "signature": headline.signature,
        "offset": _finite(result.offset.value) if result.offset else None,
        "offset_stderr": _finite(result.offset.stderr) if result.offset else None,
    }
    return rows


def _add(
    where: dict[str, Any], fit: tuple[dict[str, Any], list[dict[str, Any]]]
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    return {**where, **fit[0]}, fit[1]
