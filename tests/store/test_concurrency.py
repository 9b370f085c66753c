"""Eight processes adding results to one PostgreSQL store at once: nothing lost, nothing doubled."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest
from sqlalchemy import func, select

from ncmeasure.formats.results import Results, write_results
from ncmeasure.store import open_store
from ncmeasure.store import schema as t

PROCESSES = 8


def test_eight_processes_add_concurrently(
    pg_url: str, make_results: Callable[..., Results], tmp_path: Path
) -> None:
    # 8 machines × 3 measurements; every process also adds its neighbour's first file,
    # so each of those is added twice at the same time by two processes.
    files: dict[int, list[Path]] = {}
    for machine in range(PROCESSES):
        files[machine] = []
        for index in range(3):
            path = tmp_path / f"m{machine}-{index}.json"
            write_results(
                make_results(f"202{6 + index}-0{machine + 1}-01T08:00:00+00:00", 1 + 0.01 * index),
                path,
            )
            files[machine].append(path)
    script = (  # one process: open the store, add its files one after the other
        "import sys\n"
        "from ncmeasure.formats.results import load_results\n"
        "from ncmeasure.store import MeasurementInfo, open_store\n"
        "with open_store(sys.argv[1], write=True) as store:\n"
        "    for serial, path in zip(sys.argv[2::2], sys.argv[3::2]):\n"
        "        added = store.add(load_results(path), MeasurementInfo(serial=serial))\n"
        "        print(serial, added.measurement_id, 'added' if added.new else 'already stored')\n"
    )
    jobs = []
    for machine in range(PROCESSES):
        neighbour = (machine + 1) % PROCESSES
        todo = [(f"M{machine}", p) for p in files[machine]] + [
            (f"M{neighbour}", files[neighbour][0])
        ]
        arguments = [item for serial, path in todo for item in (serial, str(path))]
        jobs.append(
            subprocess.Popen(
                [sys.executable, "-c", script, pg_url, *arguments],
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
        )
    outputs = [job.communicate(timeout=600)[0] for job in jobs]
    assert [job.returncode for job in jobs] == [0] * PROCESSES, outputs
    with open_store(pg_url) as store, store.reading("count") as db:
        measurements = db.execute(select(func.count()).select_from(t.measurements)).scalar_one()
        machines = db.execute(select(func.count()).select_from(t.machines)).scalar_one()
        types = db.execute(select(func.count()).select_from(t.machine_types)).scalar_one()
        per_machine = dict(
            db.execute(
                select(t.machines.c.serial, func.count())
                .join(t.measurements, t.measurements.c.machine_id == t.machines.c.id)
                .group_by(t.machines.c.serial)
            ).all()
        )
        latest_ok = db.execute(
            select(func.count())
            .select_from(t.machines)
            .join(t.measurements, t.measurements.c.id == t.machines.c.latest_measurement_id)
            .where(t.measurements.c.measured_utc.like("2028-%"))
        ).scalar_one()
    assert measurements == PROCESSES * 3
    assert machines == PROCESSES and types == 1
    assert per_machine == {f"M{m}": 3 for m in range(PROCESSES)}
    assert latest_ok == PROCESSES  # every machine's latest is its 2028 measurement
    assert sum(out.count("already stored") for out in outputs) == PROCESSES  # each doubled once


def test_a_commit_of_a_lower_id_after_a_higher_one_changes_the_version(
    pg_url: str, make_results: Callable[..., Results], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two stations add at once: the first takes the lower measurement id but commits last.
    A dashboard that read the store between the two commits must see the store change
    again when the first commits (its version moves), not keep the page without it."""
    import threading

    import ncmeasure.store.store as store_module
    from ncmeasure.store import MeasurementInfo
    from ncmeasure.web.context import Context

    inside, go_on = threading.Event(), threading.Event()
    record = store_module.record_changes

    def held(db, serials, *args, **kwargs):  # type: ignore[no-untyped-def]
        if serials == ["SLOW"]:
            inside.set()
            assert go_on.wait(60)
        return record(db, serials, *args, **kwargs)

    monkeypatch.setattr(store_module, "record_changes", held)
    with open_store(pg_url, write=True) as store:
        store.add(make_results("2026-01-01T08:00:00+00:00"), MeasurementInfo(serial="FIRST"))
        slow = threading.Thread(
            target=store.add,
            args=(make_results("2026-02-01T08:00:00+00:00"), MeasurementInfo(serial="SLOW")),
        )
        slow.start()
        try:
            assert inside.wait(60)  # SLOW holds its measurement id, not yet committed
            store.add(make_results("2026-03-01T08:00:00+00:00"), MeasurementInfo(serial="FAST"))
            ctx = Context(store)
            between = ctx.version()
            shown = ctx.cached(between, "serials", lambda: [m.serial for m in store.machines()])
            assert shown == ["FAST", "FIRST"]
        finally:
            go_on.set()
            slow.join(60)
        after = ctx.version()
        assert after != between
        assert ctx.cached(after, "serials", lambda: [m.serial for m in store.machines()]) == [
            "FAST",
            "FIRST",
            "SLOW",
        ]
