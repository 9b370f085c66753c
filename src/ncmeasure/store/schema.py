"""The fleet store's tables (SQLAlchemy Core), the same on SQLite and PostgreSQL.

::

    machine_types   name + config_hash of the machine file (one program per type)
    machines        serial (unique), type, site, the latest measurement
    axes            per machine: X, Y, Z, ...
    measurements    one stored results.json: when, label, who, temperature, operating
                    hours, link, ncmeasure version, recording location, the results
                    themselves (compressed JSON, lossless), their SHA-256 (unique)
    axis_results    per measurement and axis: verdict, unit, the characteristics
                    (Coulomb, viscous, spread along the travel, offset)
    points          every measured point: position, direction, velocity, median, ...
    fits            every fit per position and direction (linear, stribeck, extended)
    fit_parameters  the parameters of a fit with standard error or 95 % interval
    causes          the likely assembly causes of the position signature, ranked
    baseline_changes per machine's (latest, baseline) pair: how they met (compared,
                    refused by the comparability rules, no point matched) and the
                    version of the diagnosis that compared them
    axis_changes    per pair and axis: the diagnosis of the change since the baseline
                    (its pattern along the travel, its cause, its spread and mean)
    machine_summaries per machine, what the lists show, kept current on adding: serial,
                    type, site, measurements, the latest and the baseline measurement,
                    the status as of the fleet it was judged in (``fleet_version``), and
                    the case-folded text a search looks in
    axis_statuses   per machine and axis: its status without the fleet (the verdict, the
                    change since the baseline, the sibling axes; default limits), for the
                    (latest, baseline) pair and diagnosis version it was judged for
    store_state     one row: the store's revision, one more with every transaction that
                    adds measurements or stores `store refresh`'s changes, in the order
                    they commit

The schema changes only through an Alembic revision (``migrations/versions``);
``tests/store/test_migrations.py`` proves the revisions build exactly these tables.
"""

from __future__ import annotations

from sqlalchemy import (
    BigInteger,
    Boolean,
    Column,
    Float,
    ForeignKey,
    ForeignKeyConstraint,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Table,
    Text,
    UniqueConstraint,
)

__all__ = [
    "axes",
    "axis_changes",
    "axis_results",
    "axis_statuses",
    "baseline_changes",
    "causes",
    "fit_parameters",
    "fits",
    "machine_summaries",
    "machine_types",
    "machines",
    "measurements",
    "metadata",
    "points",
    "store_state",
]

metadata = MetaData(
    naming_convention={
        "ix": "ix_%(column_0_label)s",
        "uq": "uq_%(table_name)s_%(column_0_name)s",
        "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
        "pk": "pk_%(table_name)s",
    }
)

machine_types = Table(
    "machine_types",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("name", String(200), nullable=False),
    Column("config_hash", String(64), nullable=False, doc="'' when the results carry none."),
    Column("created_utc", String(32), nullable=False),
    UniqueConstraint("name", "config_hash"),
)

machines = Table(
    "machines",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("serial", String(64), nullable=False, unique=True),
    Column("type_id", ForeignKey("machine_types.id"), nullable=False, index=True),
    Column("site", String(200)),
    Column("created_utc", String(32), nullable=False),
    Column("latest_measurement_id", Integer, doc="The measurement with the latest time."),
    Index("ix_machines_type_latest", "type_id", "latest_measurement_id"),
)

axes = Table(
    "axes",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("machine_id", ForeignKey("machines.id", ondelete="CASCADE"), nullable=False),
    Column("name", String(32), nullable=False),
    UniqueConstraint("machine_id", "name"),
)

measurements = Table(
    "measurements",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("machine_id", ForeignKey("machines.id", ondelete="CASCADE"), nullable=False),
    Column("type_id", ForeignKey("machine_types.id"), nullable=False),
    Column("measured_utc", String(32), nullable=False),
    Column("added_utc", String(32), nullable=False),
    Column("label", String(64)),
    Column("operator", String(200)),
    Column("temperature_c", Float),
    Column("operating_hours", Float),
    Column("link", String(64), doc="Where the data came from: canopen, modbus, a trace, ..."),
    Column("config_hash", String(64), nullable=False),
    Column("ncmeasure_version", String(32), nullable=False),
    Column("results_format_version", Integer, nullable=False),
    Column("recording_location", Text),
    Column("results_sha256", String(64), nullable=False, unique=True),
    Column("results_json", LargeBinary, nullable=False, doc="zlib-compressed results.json."),
    Index("ix_measurements_machine_time", "machine_id", "measured_utc"),
)

axis_results = Table(
    "axis_results",
    metadata,
    Column("id", Integer, primary_key=True),
    Column(
        "measurement_id",
        ForeignKey("measurements.id", ondelete="CASCADE"),
        nullable=False,
        index=True,
    ),
    Column("axis_id", ForeignKey("axes.id", ondelete="CASCADE"), nullable=False, index=True),
    Column("axis", String(32), nullable=False),
    Column("verdict", String(16), nullable=False),
    Column("verdict_reason", Text, nullable=False),
    Column("verdict_action", Text, nullable=False),
    Column("quantity", String(16), nullable=False),
    Column("unit", String(8), nullable=False),
    Column("windows", Integer, nullable=False),
    Column("samples_used", Integer, nullable=False),
    Column("coulomb", Float),
    Column("coulomb_positive", Float),
    Column("coulomb_negative", Float),
    Column("viscous_per_m_min", Float),
    Column("spread_percent", Float),
    Column("signature", String(32)),
    Column("offset", Float),
    Column("offset_stderr", Float),
    UniqueConstraint("measurement_id", "axis"),
    # the fleet's latest figures (``store check``, the lists' statuses) read from the index
    # alone: no table row each
    Index(
        "ix_axis_results_figures",
        "measurement_id",
        "axis",
        "unit",
        "coulomb",
        "viscous_per_m_min",
        "spread_percent",
    ),
)

points = Table(
    "points",
    metadata,
    Column("id", Integer, primary_key=True),
    Column(
        "axis_result_id",
        ForeignKey("axis_results.id", ondelete="CASCADE"),
        nullable=False,
        index=True,
    ),
    Column("position_index", Integer, nullable=False),
    Column("position_mm", Float, nullable=False),
    Column("direction", String(8), nullable=False),
    Column("velocity_mm_min", Float, nullable=False),
    Column("median", Float, nullable=False),
    Column("stderr", Float),
    Column("mean", Float, nullable=False),
    Column("std", Float, nullable=False),
    Column("n", Integer, nullable=False),
)

fits = Table(
    "fits",
    metadata,
    Column("id", Integer, primary_key=True),
    Column(
        "axis_result_id",
        ForeignKey("axis_results.id", ondelete="CASCADE"),
        nullable=False,
        index=True,
    ),
    Column("position_index", Integer, nullable=False),
    Column("position_mm", Float, nullable=False),
    Column("direction", String(8), nullable=False),
    Column("model", String(16), nullable=False),
    Column("chosen", Boolean, nullable=False, doc="The model that describes this curve."),
    Column("accepted", Boolean, nullable=False, doc="Linear: χ² accepted; else identifiable."),
    Column("chi2_reduced", Float),
    Column("reason", Text),
)

fit_parameters = Table(
    "fit_parameters",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("fit_id", ForeignKey("fits.id", ondelete="CASCADE"), nullable=False, index=True),
    Column("name", String(32), nullable=False),
    Column("value", Float),
    Column("stderr", Float),
    Column("ci95_low", Float),
    Column("ci95_high", Float),
)

causes = Table(
    "causes",
    metadata,
    Column("id", Integer, primary_key=True),
    Column(
        "axis_result_id",
        ForeignKey("axis_results.id", ondelete="CASCADE"),
        nullable=False,
        index=True,
    ),
    Column("rank", Integer, nullable=False),
    Column("cause", String(32), nullable=False),
    Column("score", Float, nullable=False),
    Column("evidence", Text, nullable=False),
)

baseline_changes = Table(
    "baseline_changes",
    metadata,
    Column(
        "measurement_id",
        ForeignKey("measurements.id", ondelete="CASCADE"),
        primary_key=True,
        doc="The machine's latest measurement.",
    ),
    Column(
        "baseline_id",
        ForeignKey("measurements.id", ondelete="CASCADE"),
        primary_key=True,
        index=True,
        doc="Its baseline: the first labelled delivery, else the first.",
    ),
    Column("outcome", String(16), nullable=False, doc="compared, refused or failed."),
    Column(
        "diagnosis_version",
        Integer,
        nullable=False,
        doc="The DIAGNOSIS_VERSION that compared them (ncmeasure.store.changes).",
    ),
)

axis_changes = Table(
    "axis_changes",
    metadata,
    Column("measurement_id", Integer, primary_key=True),
    Column("baseline_id", Integer, primary_key=True),
    Column("axis", String(32), primary_key=True),
    Column("signature", String(32), nullable=False, doc="The change's pattern along the travel."),
    Column("cause", String(32), nullable=False, doc="Its leading cause (none: no change)."),
    Column("spread_percent", Float, doc="(max − min)/mean of the change along the travel."),
    Column("mean_percent", Float, doc="The mean change."),
    ForeignKeyConstraint(
        ["measurement_id", "baseline_id"],
        ["baseline_changes.measurement_id", "baseline_changes.baseline_id"],
        ondelete="CASCADE",
    ),
)

machine_summaries = Table(
    "machine_summaries",
    metadata,
    Column("machine_id", ForeignKey("machines.id", ondelete="CASCADE"), primary_key=True),
    Column("serial", String(64), nullable=False, unique=True),
    Column("machine_type", String(200), nullable=False),
    Column("config_hash", String(64), nullable=False),
    Column("site", String(200)),
    Column("measurements", Integer, nullable=False),
    Column("latest_id", Integer),
    Column("latest_utc", String(32)),
    Column("latest_label", String(64)),
    Column("baseline_id", Integer, doc="The first labelled delivery, else the first."),
    Column("baseline_utc", String(32)),
    Column("baseline_label", String(64)),
    Column("status", String(16), doc="ok, warning or critical, with the default limits."),
    Column(
        "fleet_version",
        String(64),
        doc="The fleet the status was judged in (ncmeasure.store.summaries.fleet_version); "
        "a status of another is not current.",
    ),
    Column(
        "search_text",
        Text,
        nullable=False,
        server_default="",
        doc="Serial, type and site case-folded as Python folds them, joined by U+001F: what "
        "a search looks in (ncmeasure.store.summaries.search_text).",
    ),
    Index("ix_machine_summaries_status_serial", "status", "serial"),
    Index("ix_machine_summaries_type_serial", "machine_type", "serial"),
)

axis_statuses = Table(
    "axis_statuses",
    metadata,
    Column("machine_id", ForeignKey("machines.id", ondelete="CASCADE"), primary_key=True),
    Column("axis", String(32), primary_key=True),
    Column("latest_id", Integer, nullable=False),
    Column("baseline_id", Integer, nullable=False),
    Column("diagnosis_version", Integer, nullable=False),
    Column(
        "status",
        String(16),
        nullable=False,
        doc="ok, warning or critical: the axis' status without its fleet, default limits.",
    ),
)

store_state = Table(
    "store_state",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=False, doc="1: the one row."),
    Column(
        "revision",
        BigInteger,
        nullable=False,
        doc="One more with every transaction that adds measurements or stores the changes "
        "of store refresh, counted as it commits (the row is locked until then): a reader "
        "that saw one revision sees a change as soon as any later add commits, whatever "
        "measurement ids it holds (ncmeasure.store.summaries.store_revision).",
    ),
)
