"""The fleet store at scale: add rate, one machine's check, the fleet report.

A synthetic fleet (default 10,000 machines × 4 axes × 10 measurements, one
machine type) goes into a SQLite store and, when a PostgreSQL server is
reachable (``--postgresql URL``), into PostgreSQL too. The results are one
analysed synthetic measurement of four axes (5 positions × 12 velocities × both
directions), its friction scaled per machine and measurement (a spread across
the fleet and a slow drift over each machine's life), so that every stored
measurement is distinct.

It prints, per database:

- ``store add`` rate: the last ``--timed`` measurements (1,000) go in through
  ``Store.add``, each in its own transaction as the command does it, into the
  nearly full store; only the time inside ``add`` counts. The fleet before them is
  filled through ``Store.add_many``, ``--batch`` (50) per transaction, and that rate
  is printed too;
- ``store check`` of one machine: the goal is below 0.5 s;
- the fleet overview (``store report``'s data) and the report file.

And beside them, in the same run, the baseline that answers the same check
without a store: the machine's results.json files plus the latest results.json
of every other machine of the type, read from a folder tree (the way results
were kept before the store), then the same comparison and fleet statistics.

Run:   python benchmarks/fleet.py                       (the full fleet: long)
       python benchmarks/fleet.py --machines 500 --measurements 4
       python benchmarks/fleet.py --postgresql postgresql://user@127.0.0.1:5432/db
       python benchmarks/fleet.py --postgresql auto     (a throw-away server, initdb)
       python benchmarks/fleet.py --short --postgresql auto   (a crash test, seconds; CI)
       python benchmarks/fleet.py --work /var/tmp/fleet  (keep the fleet; run again: reuse)
       python benchmarks/fleet.py --work DIR --no-sqlite --postgresql auto
                                 (PostgreSQL alone, e.g. beside a SQLite run in parallel)
       python benchmarks/fleet.py --work DIR --no-sqlite --postgresql auto --copy-fill
                                 (PostgreSQL filled with the SQLite fleet's rows of DIR)

The throw-away server of ``--postgresql auto`` runs with fsync on and PostgreSQL's
default shared buffers, as SQLite writes durably too; with ``--work`` its cluster is
kept in DIR/postgresql and reused.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from sqlalchemy import func, select

from ncmeasure.analysis.analyze import analyze
from ncmeasure.analysis.judgement.compare import compare_results
from ncmeasure.analysis.judgement.fleet import modified_z_against
from ncmeasure.formats.comparison import Limits
from ncmeasure.formats.results import Results, write_results
from ncmeasure.inputs import read_text
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording
from ncmeasure.store import MeasurementInfo, open_store
from ncmeasure.store.check import check_machine
from ncmeasure.store.overview import fleet_overview, is_outlier
from ncmeasure.store.report import write_fleet_report
from ncmeasure.store.rows import CHARACTERISTICS, rows_of_axis
from ncmeasure.store.schema import measurements

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' helpers
from tests.report.example import scaled_axis

CHECK_GOAL_S = 0.5


def _base_results(folder: Path) -> Results:
    """One analysed measurement of four axes (5 positions, 12 velocities, both directions)."""
    velocities = geometric_velocities(10.0, 15000.0, 12)
    axes = [
        SyntheticAxis(
            name=name,
            positions_mm=(50.0, 150.0, 250.0, 350.0, 450.0),
            velocities_mm_min=velocities,
            coulomb=coulomb,
        )
        for name, coulomb in (("X", 2.0), ("Y", 2.2), ("Z", 2.6), ("A", 1.4))
    ]
    recording, schedule = synthetic_recording(folder, axes, seed=1)
    return analyze(recording, schedule=schedule)


def _fleet(
    base: Results, machines: int, measurements: int, seed: int = 7, skip: int = 0
) -> Iterator[tuple[str, int, Results, MeasurementInfo]]:
    """(serial, index, results, info) of every measurement, machine by machine; the first
    ``skip`` are left out (the same fleet: a fill that was stopped goes on)."""
    rng = np.random.default_rng(seed)
    for m in range(machines):
        serial = f"HMX-{m:06d}"
        level = float(rng.normal(1.0, 0.08))  # machines of a type spread by some 8 %
        for k in range(measurements):
            when = f"{2026 + k // 12:04d}-{1 + k % 12:02d}-{1 + m % 28:02d}T08:00:00+00:00"
            factor = level * (1.0 - 0.02 * k) * float(rng.normal(1.0, 0.01))
            if m * measurements + k < skip:
                continue
            axes = {name: scaled_axis(a, factor) for name, a in base.axes.items()}
            recording = base.recording.model_copy(
                update={"directory": f"recordings/{serial}/{k}", "start_utc": when}
            )
            results = base.model_copy(
                update={"axes": axes, "recording": recording, "created_utc": when}
            )
            label = "delivery" if k == 0 else "service"
            yield serial, k, results, MeasurementInfo(serial=serial, label=label, measured_utc=when)


def _median_s(run: Callable[[], object], rounds: int) -> tuple[float, float, float]:
    times = []
    for _ in range(rounds):
        start = time.perf_counter()
        run()
        times.append(time.perf_counter() - start)
    return statistics.median(times), min(times), max(times)


def _files_check(folder: Path, serial: str, limits: Limits) -> tuple[str, int]:
    """The baseline: the same check from results.json files in ``folder/SERIAL/*.json``."""

    def load(path: Path) -> Results:
        return Results.model_validate_json(read_text(path, "results.json", 1 << 28))

    own = sorted((folder / serial).glob("*.json"))
    latest, baseline = load(own[-1]), load(own[0])
    comparison = compare_results(baseline, [latest], labels=["delivery", "latest"], limits=limits)
    status = comparison.status
    outliers = 0
    fleet: dict[tuple[str, str], list[float]] = {}
    for machine in sorted(folder.iterdir()):
        if machine.name == serial:
            continue
        other = load(sorted(machine.glob("*.json"))[-1])
        for name, axis in other.axes.items():
            row = rows_of_axis(name, axis).axis
            for c in CHARACTERISTICS:
                value = row[c.name]
                if value is not None and math.isfinite(value):
                    fleet.setdefault((name, c.name), []).append(float(value))
    for name, axis in latest.axes.items():
        row = rows_of_axis(name, axis).axis
        for c in CHARACTERISTICS:
            reference = fleet.get((name, c.name), [])
            if row[c.name] is not None and len(reference) >= limits.outlier_min_runs:
                z = modified_z_against(row[c.name], reference)
                median = float(np.median(reference))
                outliers += is_outlier(c, row[c.name], median, z, limits)
    return status, outliers


def _copy_fill(sqlite_file: Path, url: str, upto: int) -> int:
    """Fill an empty PostgreSQL store with the SQLite store's first ``upto`` measurements:
    the same rows (ids included), through COPY. Returns how many were copied.

    The rows are what ``Store.add`` wrote into SQLite; adding them again one by one would
    take hours and measure nothing new. What is timed in PostgreSQL (the last adds, the
    check, the report) runs on PostgreSQL itself."""
    import sqlite3

    import psycopg

    from ncmeasure.store import schema as t

    source = sqlite3.connect(f"file:{sqlite_file}?mode=ro", uri=True)
    top = source.execute(
        "SELECT MAX(id), COUNT(*) FROM measurements WHERE id <= ?", (upto,)
    ).fetchone()
    if not top[1]:
        raise SystemExit(f"{sqlite_file}: no measurements to copy; fill the SQLite store first")
    last_result = source.execute(
        "SELECT MAX(id) FROM axis_results WHERE measurement_id <= ?", (top[0],)
    ).fetchone()[0]
    last_fit = source.execute(
        "SELECT MAX(id) FROM fits WHERE axis_result_id <= ?", (last_result,)
    ).fetchone()[0]
    machines = "SELECT machine_id FROM measurements WHERE id <= :m"
    where = {
        "machine_types": "1",
        "machines": f"id IN ({machines})",
        "axes": f"machine_id IN ({machines})",
        "measurements": "id <= :m",
        "axis_results": "id <= :r",
        "points": "axis_result_id <= :r",
        "fits": "id <= :f",
        "fit_parameters": "fit_id <= :f",
        "causes": "axis_result_id <= :r",
    }
    bounds = {"m": top[0], "r": last_result, "f": last_fit or 0}
    with psycopg.connect(url.replace("postgresql+psycopg://", "postgresql://")) as target:
        for table in t.metadata.sorted_tables:
            if table.name not in where:
                continue
            columns = [c.name for c in table.columns]
            names = ", ".join(f'"{c}"' for c in columns)
            rows = source.execute(
                f"SELECT {names} FROM {table.name} WHERE {where[table.name]} ORDER BY id", bounds
            )
            started = time.perf_counter()
            with target.cursor().copy(f"COPY {table.name} ({names}) FROM STDIN") as copy:
                if table.name == "machines":  # the latest measurement is set below
                    latest = columns.index("latest_measurement_id")
                    rows = ((*row[:latest], None, *row[latest + 1 :]) for row in rows)
                for row in rows:
                    copy.write_row(row)
            print(
                f"  postgresql: copied {table.name} in {time.perf_counter() - started:.0f} s",
                file=sys.stderr,
            )
            target.execute(
                f"SELECT setval(pg_get_serial_sequence('{table.name}', 'id'), "
                f"COALESCE((SELECT MAX(id) FROM {table.name}), 1))"
            )
        target.execute(
            "UPDATE machines SET latest_measurement_id = (SELECT m.id FROM measurements m "
            "WHERE m.machine_id = machines.id ORDER BY m.measured_utc DESC, m.id DESC LIMIT 1)"
        )
        target.execute("ANALYZE")
    source.close()
    return int(top[1])


def _run(label: str, url: str, base: Results, args: argparse.Namespace, work: Path) -> None:
    limits = Limits()
    took = 0.0
    last = time.perf_counter()
    with open_store(url, write=True) as store:
        with store.reading("count the measurements") as db:
            stored = db.execute(select(func.count()).select_from(measurements)).scalar_one()
        total = args.machines * args.measurements
        if stored >= total:  # --work with a store of an earlier run: measure what is there
            args.machines = len(store.machines())
            print(f"{label}: reusing {args.machines} machines of {store.where}")
            total = stored = 0
        elif stored:  # a fill that was stopped (whole transactions only): it goes on
            print(f"{label}: going on after the {stored} measurements in {store.where}")
        timed_from = total - min(args.timed, total)
        if label == "postgresql" and args.copy_fill and stored == 0 and timed_from:
            start = time.perf_counter()
            stored = _copy_fill(work / "fleet.db", url, timed_from)
            print(
                f"{label}: filled with the SQLite store's first {stored} measurements (COPY) "
                f"in {time.perf_counter() - start:.0f} s"
            )
        added = stored
        batch: list[tuple[Results, MeasurementInfo]] = []
        loaded = 0.0
        todo = _fleet(base, args.machines, args.measurements, skip=stored) if total else iter(())
        for serial, k, results, info in todo:
            if added + len(batch) < timed_from:  # the fill: many per transaction
                batch.append((results, info))
                if len(batch) == args.batch or added + len(batch) == timed_from:
                    start = time.perf_counter()
                    store.add_many(batch)
                    loaded += time.perf_counter() - start
                    added += len(batch)
                    batch.clear()
            else:  # the timed adds: one per transaction, as the command does it
                start = time.perf_counter()
                store.add(results, info)
                took += time.perf_counter() - start
                added += 1
            if label == "sqlite":  # the baseline's folder tree, written once
                write_results(results, work / "files" / serial / f"{k:03d}.json")
            if time.perf_counter() - last > 30:
                last = time.perf_counter()
                print(f"  {label}: {added} measurements added ...", file=sys.stderr)
    if loaded:
        filled = min(added, timed_from) - stored
        print(
            f"{label}: filled with {filled} measurements, {args.batch} per transaction: "
            f"{filled / loaded:8.1f} measurements/s"
        )
    if took:
        timed = added - max(timed_from, stored)
        print(
            f"{label}: store add {timed / took:8.1f} measurements/s (the last {timed}, "
            f"one per transaction, in {took:.1f} s)"
        )
    serial = f"HMX-{args.machines // 2:06d}"
    with open_store(url) as store:
        median, low, high = _median_s(lambda: check_machine(store, serial, limits), args.rounds)
        status = check_machine(store, serial, limits).status
        goal = "meets" if median < CHECK_GOAL_S else "misses"
        print(
            f"{label}: store check {median:8.3f} s (range {low:.3f}–{high:.3f}, status {status}); "
            f"goal < {CHECK_GOAL_S} s: {goal}"
        )
        start = time.perf_counter()
        overview = fleet_overview(store, limits)
        between = time.perf_counter()
        write_fleet_report(store, overview, work / f"fleet-{label}.html", trends=args.trends)
        end = time.perf_counter()
    size = (work / f"fleet-{label}.html").stat().st_size / 1e6
    print(
        f"{label}: fleet overview {between - start:8.3f} s, report (up to {args.trends} trends) "
        f"{end - between:.3f} s ({size:.1f} MB, {len(overview.outliers)} outliers)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--machines", type=int, default=10_000)
    parser.add_argument("--measurements", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=5, help="Rounds of each timed check.")
    parser.add_argument("--trends", type=int, default=12)
    parser.add_argument(
        "--timed",
        type=int,
        default=1000,
        help="The last N measurements are added one per transaction and timed (store add).",
    )
    parser.add_argument(
        "--batch", type=int, default=50, help="Measurements per transaction while filling."
    )
    parser.add_argument(
        "--postgresql",
        metavar="URL",
        help="An empty PostgreSQL database, or 'auto': a throw-away server (initdb).",
    )
    parser.add_argument("--short", action="store_true", help="A small fleet: a crash test.")
    parser.add_argument(
        "--copy-fill",
        action="store_true",
        help="Fill PostgreSQL with the rows of the SQLite fleet in --work DIR (COPY), then add "
        "and time the last --timed measurements; hours faster than adding them all.",
    )
    parser.add_argument(
        "--no-sqlite",
        action="store_true",
        help="Skip the SQLite store and the results.json baseline (it is written beside it).",
    )
    parser.add_argument(
        "--work",
        metavar="DIR",
        help="Keep the stores and files here; a later run with the same DIR reuses them "
        "(a fleet of 100,000 measurements takes hours to add).",
    )
    args = parser.parse_args()
    if args.short:
        args.machines, args.measurements, args.rounds, args.trends = 6, 2, 1, 2
        args.timed, args.batch = 4, 3
    with tempfile.TemporaryDirectory(prefix="ncmeasure-fleet-") as tmp:
        work = Path(args.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        base = _base_results(Path(tmp) / "run")  # the same each time (seed)
        print(
            f"fleet: {args.machines} machines × {len(base.axes)} axes × {args.measurements} "
            "measurements, one machine type"
        )
        if not args.no_sqlite:
            _run("sqlite", f"sqlite:///{work / 'fleet.db'}", base, args, work)
        if args.postgresql == "auto":
            from tests.pg import temporary_postgres

            kept = work / "postgresql" if args.work else None
            with temporary_postgres(kept, fsync=True, shared_buffers="128MB") as url:
                _run("postgresql", url, base, args, work)
        elif args.postgresql:
            _run("postgresql", args.postgresql, base, args, work)
        if args.no_sqlite:
            return
        serial = f"HMX-{args.machines // 2:06d}"
        median, low, high = _median_s(
            lambda: _files_check(work / "files", serial, Limits()), args.rounds
        )
        status, outliers = _files_check(work / "files", serial, Limits())
        print(
            f"baseline (results.json files): the same check {median:8.3f} s "
            f"(range {low:.3f}–{high:.3f}, status {status}, {outliers} outlier figures)"
        )


if __name__ == "__main__":
    main()
