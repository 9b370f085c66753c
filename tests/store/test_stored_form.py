"""What adding keeps, byte for byte and value for value.

A measurement's identity is the SHA-256 of its canonical JSON: the same results must give
the same bytes in every release, or a measurement stored before would be stored again. Its
rows go in as multi-row INSERTs (SQLite) or COPY (PostgreSQL): every value must come back
as it was, text with tabs, backslashes, line ends and non-ASCII letters included.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from typing import Any

from sqlalchemy import select

from ncmeasure.formats.results import AxisResult, Results
from ncmeasure.store import MeasurementInfo, open_store
from ncmeasure.store import schema as t
from ncmeasure.store.rows import POINT_COLUMNS, canonical_json, results_digest

Make = Callable[..., Results]

ODD_TEXT = "tab\there, back\\slash, line\nend, NUL-free: χ² — Grüße \u2028 \U0001f527"
ODD_FLOATS = [1e-05, 1e16, -0.0, 5e-324, 1.7976931348623157e308, 0.1, 1e-4, 123456789.125]


def _odd(results: Results) -> Results:
    """``results`` with the values a serializer gets wrong: tiny and huge floats, negative
    zero, the smallest subnormal, None, text with escapes and letters beyond ASCII."""
    data = results.model_dump(mode="json")
    axis = data["axes"]["X"]
    axis["verdict"]["reason"] = ODD_TEXT
    found = axis["positions"][0]["directions"]["positive"]
    for point, value in zip(found["points"], ODD_FLOATS, strict=False):
        point["mean"] = value
        point["stderr"] = None
    found["fit"]["reason"] = ODD_TEXT
    return Results.model_validate(data)


def test_the_canonical_json_is_sorted_compact_ascii_json(make_results: Make) -> None:
    """The bytes are those of ``json.dumps`` (sorted keys, no spaces, ASCII escapes) of the
    JSON dump: a faster serializer must give these bytes or not be used."""
    results = _odd(make_results("2026-01-10T08:00:00+00:00"))
    canonical = canonical_json(results)
    expected = json.dumps(
        results.model_dump(mode="json"),
        sort_keys=True,
        separators=(",", ":"),
        ensure_ascii=True,
        allow_nan=False,
    ).encode("ascii")
    assert canonical == expected
    odd = [f'"mean":{v}'.encode() for v in ("1e-05", "1e+16", "-0.0", "5e-324", "0.0001")]
    odd += [b'"mean":1.7976931348623157e+308', b'"mean":0.1', b'"stderr":null']
    odd += [b"\\u03c7\\u00b2", b"\\ud83d\\udd27", b"tab\\there"]
    for text in odd:
        assert text in canonical, text
    assert canonical.isascii()
    # the identity: the same results, the same digest, whatever their object's history
    again = Results.model_validate_json(canonical)
    assert results_digest(canonical_json(again)) == results_digest(canonical)


def _points(results: Results) -> list[tuple[Any, ...]]:
    out = []
    for name, axis in results.axes.items():
        for position in axis.positions:
            for direction, found in position.directions.items():
                for p in found.points if found is not None else ():
                    finite = p.stderr is not None and math.isfinite(p.stderr)
                    where = (name, position.position_index, position.position_mm, direction)
                    figures = (p.velocity_mm_min, p.median, p.stderr if finite else None)
                    out.append((*where, *figures, p.mean, p.std, p.n))
    return sorted(out, key=repr)


def _linear_fits(axis_name: str, axis: AxisResult) -> list[tuple[Any, ...]]:
    return [
        (axis_name, position.position_index, direction, found.fit.reason, found.fit.coulomb)
        for position in axis.positions
        for direction, found in position.directions.items()
        if found is not None and found.fit is not None
    ]


def test_every_row_comes_back_as_it_went_in(store_url: str, make_results: Make) -> None:
    """A batch of two machines: every point row (each column) and the linear fits' texts
    and figures read back equal the results' own values."""
    first = _odd(make_results("2026-01-10T08:00:00+00:00"))
    second = make_results("2026-02-10T08:00:00+00:00", 0.9)
    with open_store(store_url, write=True) as store:
        store.add_many(
            [(first, MeasurementInfo(serial="M1")), (second, MeasurementInfo(serial="M2"))]
        )
        p, a, m, f, fp = t.points, t.axis_results, t.measurements, t.fits, t.fit_parameters
        columns = [a.c.axis, *(p.c[name] for name in POINT_COLUMNS)]
        with store.reading("read the rows") as db:
            stored = {
                serial: sorted(
                    (
                        tuple(row)
                        for row in db.execute(
                            select(*columns)
                            .join(a, a.c.id == p.c.axis_result_id)
                            .join(m, m.c.id == a.c.measurement_id)
                            .join(t.machines, t.machines.c.id == m.c.machine_id)
                            .where(t.machines.c.serial == serial)
                        )
                    ),
                    key=repr,
                )
                for serial in ("M1", "M2")
            }
            fits = sorted(
                (row.axis, row.position_index, row.direction, row.reason, row.value)
                for row in db.execute(
                    select(a.c.axis, f.c.position_index, f.c.direction, f.c.reason, fp.c.value)
                    .join(a, a.c.id == f.c.axis_result_id)
                    .join(fp, fp.c.fit_id == f.c.id)
                    .join(m, m.c.id == a.c.measurement_id)
                    .join(t.machines, t.machines.c.id == m.c.machine_id)
                    .where(
                        t.machines.c.serial == "M1",
                        f.c.model == "linear",
                        fp.c.name == "coulomb",
                    )
                )
            )
    assert stored["M1"] == _points(first)
    assert stored["M2"] == _points(second)
    expected = sorted(row for name, axis in first.axes.items() for row in _linear_fits(name, axis))
    assert fits == expected
    assert ODD_TEXT in {row[3] for row in fits}
