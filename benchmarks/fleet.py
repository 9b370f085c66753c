"""The fleet store at scale: filling it, and every CLI command, REST endpoint and dashboard
page over it, at several fleet sizes on SQLite and PostgreSQL.

A synthetic fleet (one machine type, four axes of 5 positions × 12 velocities × both
directions, ``--measurements`` per machine, default 2) is added through the store's batch
``Store.add_many`` (``--batch`` per transaction, default 50), for each size of
``--machines`` (default 100,1000,10000: the largest holds 20,000 measurements). It prints:

- the fill rate (measurements per second, wall and CPU, the time inside ``add_many``), and
  beside it its floor: the CPU of turning the same results into their stored form alone
  (canonical JSON, digest, compression), which every add pays;
- per CLI command (run as ``python -m ncmeasure``, as a user runs it): wall and CPU time
  of the process, its peak memory and the output's size; beside them ``python -c pass``;
- per REST endpoint and dashboard page (the application in this process, through
  FastAPI's test client): wall and CPU of the median of the requests after the first
  (the application caches per store version), and of the first, which the goal and
  the growth judge (it is the one after every change of the store), the peak of
  Python's allocations, and the response's size;
- the growth of each from the second-largest fleet to the largest.

Before the commands, the store is brought to a store in use (``store refresh`` once after
a fill, which keeps every machine's own status) and changed: one more measurement of one
machine, so that every command and page measured is the first after a change.

The goals (docs/performance.md): at 10,000 machines every CLI command ≤ 2 s, every page
and endpoint ≤ 0.3 s and ≤ 500 kB; growth from 1,000 to 10,000 below 2 ×; 20,000
measurements filled in ≤ 20 s. CPU is the figure judged (the box is shared); wall beside.

With ``--block B`` only the first B machines (B divides every size) are added through
``add_many``; the rest are copies of them made in the database (every table's rows with
their ids shifted and the serials, digests renamed): the same rows a fill makes, the
fleet's values repeating every B machines, in minutes instead of an hour for 10,000
machines on a busy box. The fill rate is then that of the block.

Run:   python benchmarks/fleet.py                         (SQLite; the 10,000: long)
       python benchmarks/fleet.py --block 500 --work DIR  (10,000 machines by copies)
       python benchmarks/fleet.py --machines 100,1000 --postgresql auto
       python benchmarks/fleet.py --short --postgresql auto    (a crash test: seconds; CI)
       python benchmarks/fleet.py --work DIR              (keep the stores; run again: reuse)
       python benchmarks/fleet.py --machines 10000 --fill-only --postgresql auto   (the fill)
"""

from __future__ import annotations

import argparse
import datetime as dt
import statistics
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from ncmeasure.analysis.analyze import analyze
from ncmeasure.formats.results import Results
from ncmeasure.sim.synthetic import SyntheticAxis, geometric_velocities, synthetic_recording
from ncmeasure.store import MeasurementInfo, open_store
from ncmeasure.store.database import connect, display_url
from ncmeasure.store.rows import canonical_json, compress, results_digest

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the tests' helpers
from tests.report.example import scaled_axis

CLI_GOAL_S = 2.0
PAGE_GOAL_S = 0.3
PAGE_GOAL_KB = 500.0
FILL_GOAL = 20_000, 20.0  # measurements, seconds

Figures = dict[tuple[str, str], tuple[float, float]]
"""Per (database, item): (CPU s, wall s) at one fleet size."""


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
    base: Results, machines: int, measurements: int, seed: int = 7
) -> Iterator[tuple[Results, MeasurementInfo]]:
    """Every measurement, machine by machine: friction spread by some 8 % across the fleet,
    drifting over each machine's life; every fiftieth machine worn by a third (warnings)."""
    rng = np.random.default_rng(seed)
    for m in range(machines):
        serial = f"HMX-{m:06d}"
        level = float(rng.normal(1.0, 0.08))
        site = f"hall {1 + m % 7}"
        for k in range(measurements):
            when = f"{2026 + k // 12:04d}-{1 + k % 12:02d}-{1 + m % 28:02d}T08:00:00+00:00"
            factor = level * (1.0 - 0.02 * k) * float(rng.normal(1.0, 0.01))
            if k and m % 50 == 0:
                factor *= 0.67
            axes = {name: scaled_axis(a, factor) for name, a in base.axes.items()}
            recording = base.recording.model_copy(
                update={"directory": f"recordings/{serial}/{k}", "start_utc": when}
            )
            results = base.model_copy(
                update={"axes": axes, "recording": recording, "created_utc": when}
            )
            label = "delivery" if k == 0 else "service"
            yield results, MeasurementInfo(serial=serial, label=label, site=site, measured_utc=when)


def _fill(url: str, base: Results, machines: int, args: argparse.Namespace) -> None:
    """Fill the store (unless it holds the fleet already) and print the rate."""
    with open_store(url, write=True) as store:
        held = store.machine_page(limit=1).total
    if held >= machines:
        print(f"    reusing the {machines} machines of {display_url(url)}")
        return
    block = machines if args.block is None else min(args.block, machines)
    if machines % block:
        raise SystemExit(f"--block {block} does not divide {machines} machines")
    if held < block:
        _fill_block(url, base, block, args)
    if block < machines:
        start = time.perf_counter()
        _replicate(url, block, machines)
        print(
            f"    {machines - block} machines copied from the first {block} in the database "
            f"({time.perf_counter() - start:.0f} s wall)"
        )


def _fill_block(url: str, base: Results, machines: int, args: argparse.Namespace) -> None:
    """Add the first ``machines`` machines through ``add_many`` and print the rate."""
    with open_store(url, write=True) as store:
        wall = cpu = 0.0
        floor = 0.0
        added = 0
        batch: list[tuple[Results, MeasurementInfo]] = []
        last = time.perf_counter()
        for one in _fleet(base, machines, args.measurements):
            batch.append(one)
            if len(batch) < args.batch:
                continue
            wall, cpu = _add(store, batch, wall, cpu)
            if added < 200:  # the floor, on the first few hundred
                floor += _stored_form_cpu(batch)
            added += len(batch)
            batch = []
            if time.perf_counter() - last > 30:
                last = time.perf_counter()
                print(f"    {added} measurements added ...", file=sys.stderr)
        if batch:
            wall, cpu = _add(store, batch, wall, cpu)
            added += len(batch)
    sampled = min(added, max(200, args.batch))
    goal_n, goal_s = FILL_GOAL
    projected = goal_n / (added / cpu)
    met = "met" if projected <= goal_s else "NOT met"
    floor_rate = sampled / floor
    print(
        f"    fill: {added} measurements, {args.batch} per transaction: "
        f"{added / cpu:7.1f}/s CPU, {added / wall:7.1f}/s wall; {goal_n:,} would take "
        f"{projected:.0f} s CPU (goal ≤ {goal_s:.0f} s: {met}); "
        f"floor (stored form alone): {floor_rate:7.1f}/s CPU, the fill at "
        f"{floor_rate / (added / cpu):.2f} × its time; {goal_n:,} stored forms alone take "
        f"{goal_n / floor_rate:.0f} s CPU"
    )


_SHIFTED = {
    "id": None,  # the table's own
    "machine_id": "machines",
    "measurement_id": "measurements",
    "latest_measurement_id": "measurements",
    "latest_id": "measurements",
    "baseline_id": "measurements",
    "axis_id": "axes",
    "axis_result_id": "axis_results",
    "fit_id": "fits",
}
"""Id columns and the table their ids point into (machine_types are shared, not copied)."""


def _replicate(url: str, block: int, machines: int) -> None:
    """Copy machines 1..block (ids 1..block, serials HMX-000000...) until there are
    ``machines``: each copy's ids shifted past the last, serials and digests renamed."""
    from sqlalchemy import func, insert, literal, select

    from ncmeasure.store import schema as t

    with connect(url, write=True) as engine, engine.begin() as db:
        highest = {
            table.name: int(db.execute(select(func.max(table.c.id))).scalar_one() or 0)
            for table in t.metadata.sorted_tables
            if "id" in table.c and table.name not in ("machine_types", "store_state")
        }
        named = [t.machines, t.machine_summaries]
        rows = {
            table.name: [dict(r._mapping) for r in db.execute(select(table))] for table in named
        }
        for copy in range(1, machines // block):
            shift = {name: copy * top for name, top in highest.items()}
            for table in t.metadata.sorted_tables:
                if table.name in ("machine_types", "alembic_version", "store_state"):
                    continue
                if table in named:
                    db.execute(
                        insert(table), [_shifted(r, table.name, shift) for r in rows[table.name]]
                    )
                    continue
                columns = []
                for column in table.c:
                    target = _SHIFTED.get(column.name, "")
                    if target != "" and (target or table.name) in shift:
                        columns.append(column + shift[target or table.name])
                    elif column.name == "results_sha256":
                        columns.append(literal(f"{copy:04x}") + func.substr(column, 5))
                    else:
                        columns.append(column)
                # the block's rows: by their own id, else by their measurement or machine
                key = next(k for k in ("id", "measurement_id", "machine_id") if k in table.c)
                own = table.c[key]
                top = highest[
                    {"id": table.name, "measurement_id": "measurements"}.get(key, "machines")
                ]
                copied = select(*columns).where(own <= top)  # the block's rows alone
                db.execute(insert(table).from_select(list(table.c.keys()), copied))
        _advance_sequences(db)
        # the copies are adds the store did not count: a revision of its own
        db.execute(t.store_state.update().values(revision=t.store_state.c.revision + 1))


def _advance_sequences(db: object) -> None:
    """On PostgreSQL, each table's id sequence past the ids the copies were given."""
    from sqlalchemy import text

    from ncmeasure.store import schema as t

    if db.dialect.name != "postgresql":  # type: ignore[attr-defined]
        return
    for table in t.metadata.sorted_tables:
        if "id" in table.c and table.c.id.autoincrement in (True, "auto"):
            db.execute(  # type: ignore[attr-defined]
                text(
                    f"SELECT setval(pg_get_serial_sequence('{table.name}', 'id'), "
                    f"(SELECT COALESCE(MAX(id), 1) FROM {table.name}))"
                )
            )


def _shifted(row: dict[str, object], table: str, shift: dict[str, int]) -> dict[str, object]:
    out = dict(row)
    for name, value in row.items():
        target = _SHIFTED.get(name, "")
        if target != "" and value is not None:
            out[name] = int(value) + shift[target or table]  # type: ignore[call-overload]
    machine_id = int(out["machine_id" if table == "machine_summaries" else "id"])  # type: ignore[call-overload]
    out["serial"] = f"HMX-{machine_id - 1:06d}"
    if table == "machine_summaries":
        from ncmeasure.store.summaries import search_text

        out["search_text"] = search_text(out["serial"], out["machine_type"], out["site"])  # type: ignore[arg-type]
    return out


def _add(
    store: object, batch: list[tuple[Results, MeasurementInfo]], wall: float, cpu: float
) -> tuple[float, float]:
    start, start_cpu = time.perf_counter(), time.process_time()
    store.add_many(batch)  # type: ignore[attr-defined]
    return wall + time.perf_counter() - start, cpu + time.process_time() - start_cpu


def _stored_form_cpu(batch: list[tuple[Results, MeasurementInfo]]) -> float:
    start = time.process_time()
    for results, _ in batch:
        canonical = canonical_json(results)
        results_digest(canonical)
        compress(canonical)
    return time.process_time() - start


def _settle(url: str) -> None:
    """A store in use: every machine's own status kept (``store refresh`` once, after a
    fill that kept none)."""
    from ncmeasure.store.statuses import fleet_statuses

    with open_store(url, write=True) as store, store.reading("count") as db:
        from sqlalchemy import func, select

        from ncmeasure.store import schema as t

        kept = db.execute(select(func.count()).select_from(t.axis_statuses)).scalar_one()
    if kept:
        return
    start, start_cpu = time.perf_counter(), time.process_time()
    with open_store(url, write=True) as store:
        store.refresh_summaries()
        fleet_statuses(store)
    print(
        f"    store refresh (once, after the fill): {time.process_time() - start_cpu:.1f} s "
        f"CPU, {time.perf_counter() - start:.1f} s wall"
    )


def _change(url: str, base: Results, serial: str, when: str | None = None) -> None:
    """A change of the store: one more measurement of one machine, as a user adds it; every
    command and page after it is the first after a change."""
    when = when or time.strftime("%Y-%m-%dT%H:%M:%S+00:00", time.gmtime())
    recording = base.recording.model_copy(update={"directory": f"now/{when}", "start_utc": when})
    results = base.model_copy(update={"recording": recording, "created_utc": when})
    with open_store(url, write=True) as store:
        store.add(results, MeasurementInfo(serial=serial, label="service", measured_utc=when))
    print(f"    one measurement of {serial} added: the figures below are the first after it")


AFTER_A_CHANGE = (
    "GET / (the grid)",
    "GET /api/v1/machines/{serial}/check",
    "GET /machines/{serial}/axes/X (its page)",
)
"""Requested again in the running server after a measurement of another machine."""


def _child(argv: list[str]) -> tuple[float, float, float, int]:
    """Run a process: (wall s, CPU s, peak memory MiB, bytes written to stdout). GNU time
    measures it: the resource usage of a forked child counts the parent's memory."""
    with tempfile.NamedTemporaryFile("r", suffix=".time") as measured:
        start = time.perf_counter()
        done = subprocess.run(
            ["/usr/bin/time", "-o", measured.name, "-f", "%U %S %M", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            check=False,
        )
        wall = time.perf_counter() - start
        user, system, peak_kb = measured.read().split()[-3:]
    if done.returncode not in (0, 1, 3):  # 1, 3: a warning or critical status
        raise SystemExit(f"{' '.join(argv)}: exit code {done.returncode}")
    return wall, float(user) + float(system), int(peak_kb) / 1024, len(done.stdout)


def _cli(label: str, url: str, serial: str, work: Path, figures: Figures) -> None:
    report = work / f"report-{label}.html"
    commands = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "store list": ["store", "list"],
        "store list --json --limit 1000": ["store", "list", "--json", "--limit", "1000"],
        "store list --search": ["store", "list", "--search", serial],
        "store list --status warning": ["store", "list", "--status", "warning"],
        "store show": ["store", "show", serial],
        "store check": ["store", "check", serial],
        "store report": ["store", "report", "-q", "-o", str(report), "--trends", "3"],
    }
    for name, argv in commands.items():
        if argv[0] == "store":
            argv = [sys.executable, "-m", "ncmeasure", *argv, "--store", url]
        wall, cpu, memory, size = _child(argv)
        if name == "store report":
            size = report.stat().st_size
        met = "" if name.startswith("python") else _goal(cpu, CLI_GOAL_S)
        print(
            f"    cli  {name:<32} {cpu:7.3f} s CPU {wall:7.3f} s wall {memory:6.0f} MiB "
            f"{size / 1e3:8.1f} kB {met}"
        )
        figures[(label, f"cli  {name}")] = cpu, wall


def _goal(value: float, goal: float) -> str:
    return f"(goal ≤ {goal:g}: {'met' if value <= goal else 'NOT met'})"


def _web(
    label: str,
    url: str,
    machines: int,
    base: Results,
    args: argparse.Namespace,
    figures: Figures,
) -> None:
    serial = f"HMX-{machines // 2:06d}"
    from fastapi.testclient import TestClient

    from ncmeasure.web import create_app

    paths = {
        "GET /api/v1/machines": "/api/v1/machines",
        "GET /api/v1/machines?limit=1000": "/api/v1/machines?limit=1000",
        "GET /api/v1/machines?search=": f"/api/v1/machines?search={serial}",
        "GET /api/v1/machines/{serial}": f"/api/v1/machines/{serial}",
        "GET /api/v1/machines/{serial}/check": f"/api/v1/machines/{serial}/check",
        "GET / (the grid)": "/",
        "GET /?q= (a search)": f"/?q={serial}",
        "GET /?status=warning": "/?status=warning",
        "GET /machines/{serial}": f"/machines/{serial}",
        "GET /machines/{serial}/axes/X/trend.svg": f"/machines/{serial}/axes/X/trend.svg",
        "GET /machines/{serial}/axes/X (its page)": f"/machines/{serial}/axes/X",
        "GET /api/v1/machines/{serial}/measurements": f"/api/v1/machines/{serial}/measurements",
        "GET /api/v1/machines/{serial}/axes/X/trend": f"/api/v1/machines/{serial}/axes/X/trend",
    }
    with TestClient(create_app(url), base_url="http://127.0.0.1") as client:
        with open_store(url) as store:
            latest = store.machine(serial)[1][-1].id
        paths["GET /api/v1/measurements/{id}/results"] = f"/api/v1/measurements/{latest}/results"
        for name, path in paths.items():
            first = _request(client, path)
            warm = [_request(client, path) for _ in range(args.rounds)]
            cpu = statistics.median(w[0] for w in warm)
            wall = statistics.median(w[1] for w in warm)
            tracemalloc.start()
            client.get(path)
            peak = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            size = first[2] / 1e3
            # judged on the first request: the one after every change of the store
            met = "met" if first[0] <= PAGE_GOAL_S and size <= PAGE_GOAL_KB else "NOT met"
            print(
                f"    web  {name:<40} {cpu:7.3f} s CPU {wall:7.3f} s wall (first {first[0]:.3f} "
                f"s CPU) {peak:6.1f} MiB {size:8.1f} kB (goal ≤ {PAGE_GOAL_S} s, ≤ "
                f"{PAGE_GOAL_KB:.0f} kB: {met})"
            )
            figures[(label, f"web  {name}")] = first[0], first[1]
        # A dashboard stays up while measurements come in: the first request after one,
        # a measurement of another machine each round.
        after: dict[str, list[tuple[float, float, int]]] = {name: [] for name in AFTER_A_CHANGE}
        for k in range(args.rounds):
            other = f"HMX-{(int(serial[4:]) + 1 + k) % machines:06d}"
            when = dt.datetime.now(dt.UTC).isoformat(timespec="microseconds")
            _change(url, base, other, when)
            for name in AFTER_A_CHANGE:
                after[name].append(_request(client, paths[name]))
        for name, found in after.items():
            cpu = statistics.median(f[0] for f in found)
            wall = statistics.median(f[1] for f in found)
            size = max(f[2] for f in found) / 1e3
            met = "met" if cpu <= PAGE_GOAL_S and size <= PAGE_GOAL_KB else "NOT met"
            shown = f"{name}, server up"
            print(
                f"    web  {shown:<40} {cpu:7.3f} s CPU {wall:7.3f} s wall (median of "
                f"{len(found)}, {min(f[0] for f in found):.3f}–{max(f[0] for f in found):.3f} "
                f"s; each the first after a measurement of another machine) "
                f"(goal ≤ {PAGE_GOAL_S} s: {met})"
            )
            figures[(label, f"web  {shown}")] = cpu, wall


def _request(client: object, path: str) -> tuple[float, float, int]:
    start, start_cpu = time.perf_counter(), time.process_time()
    response = client.get(path)  # type: ignore[attr-defined]
    if response.status_code != 200:
        raise SystemExit(f"{path}: {response.status_code} {response.text[:200]}")
    return time.process_time() - start_cpu, time.perf_counter() - start, len(response.content)


def _one_size(
    label: str, url: str, machines: int, base: Results, args: argparse.Namespace, work: Path
) -> Figures:
    print(f"  {label}, {machines} machines × {args.measurements} measurements:")
    _fill(url, base, machines, args)
    serial = f"HMX-{machines // 2:06d}"
    _settle(url)
    _change(url, base, serial)
    figures: Figures = {}
    if args.fill_only:
        return figures
    if not args.short or machines == max(args.sizes):  # a crash test runs each command once
        _cli(label, url, serial, work, figures)
    _web(label, url, machines, base, args, figures)
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--machines", default="100,1000,10000", help="Fleet sizes, comma-separated."
    )
    parser.add_argument("--measurements", type=int, default=2, help="Per machine.")
    parser.add_argument("--batch", type=int, default=50, help="Measurements per transaction.")
    parser.add_argument(
        "--block",
        type=int,
        help="Add this many machines through add_many, copy them in the database for the rest.",
    )
    parser.add_argument("--rounds", type=int, default=5, help="Requests per endpoint, warm.")
    parser.add_argument(
        "--postgresql",
        metavar="URL",
        help="A PostgreSQL server (a database per size is made), or 'auto': a throw-away one.",
    )
    parser.add_argument("--no-sqlite", action="store_true", help="PostgreSQL alone.")
    parser.add_argument("--short", action="store_true", help="A small fleet: a crash test.")
    parser.add_argument(
        "--fill-only", action="store_true", help="Fill the stores and print the rate alone."
    )
    parser.add_argument("--work", metavar="DIR", help="Keep the stores here and reuse them.")
    args = parser.parse_args()
    sizes = [int(n) for n in args.machines.split(",")]
    if args.short:
        sizes, args.measurements, args.batch, args.rounds = [4, 8], 2, 5, 1
    args.sizes = sizes
    with tempfile.TemporaryDirectory(prefix="ncmeasure-fleet-") as tmp:
        work = Path(args.work or tmp)
        work.mkdir(parents=True, exist_ok=True)
        base = _base_results(Path(tmp) / "run")
        print(f"fleet: {sizes} machines × {len(base.axes)} axes × {args.measurements} measurements")
        print(f"load {_load()}")
        found: dict[int, Figures] = {}
        with _Postgres(args, work) as server:
            for machines in sizes:
                found[machines] = {}
                if not args.no_sqlite:
                    url = f"sqlite:///{work / f'fleet-{machines}.db'}"
                    found[machines] |= _one_size("sqlite", url, machines, base, args, work)
                if server is not None:
                    url = _pg_database(server, f"fleet_{machines}")
                    found[machines] |= _one_size("postgresql", url, machines, base, args, work)
        if len(sizes) >= 2:
            low, high = sizes[-2], sizes[-1]
            print(f"growth {low} → {high} machines ({high / low:g} ×), CPU (goal < 2 ×):")
            for key, (cpu, _) in sorted(found[high].items()):
                before = found[low].get(key)
                if before and before[0] > 0:
                    ratio = cpu / before[0]
                    flag = "" if ratio < 2 else "  NOT met"
                    print(f"  {key[0]:<10} {key[1]:<37} {ratio:6.2f} ×{flag}")
        print(f"load {_load()}")


def _load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


class _Postgres:
    """The PostgreSQL server: --postgresql URL, a throw-away one ('auto'), or none."""

    def __init__(self, args: argparse.Namespace, work: Path) -> None:
        self.args, self.work = args, work
        self._context: object = None

    def __enter__(self) -> str | None:
        if self.args.postgresql != "auto":
            return str(self.args.postgresql) if self.args.postgresql else None
        from tests.pg import temporary_postgres

        kept = self.work / "postgresql" if self.args.work else None
        self._context = temporary_postgres(kept, fsync=True, shared_buffers="128MB")
        return str(self._context.__enter__())  # type: ignore[attr-defined]

    def __exit__(self, *exc: object) -> None:
        if self._context is not None:
            self._context.__exit__(*exc)  # type: ignore[attr-defined]


def _pg_database(server: str, name: str) -> str:
    """The URL of database ``name`` on the server, created when missing."""
    import psycopg

    plain = server.replace("postgresql+psycopg://", "postgresql://")
    with psycopg.connect(plain, autocommit=True) as connection:
        if not connection.execute(
            "SELECT 1 FROM pg_database WHERE datname = %s", (name,)
        ).fetchone():
            connection.execute(f'CREATE DATABASE "{name}"')
    head, _, _ = server.rpartition("/")
    return f"{head}/{name}"


if __name__ == "__main__":
    main()
