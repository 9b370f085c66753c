"""Options several commands share, and the reading of ``KEY=VALUE`` option values."""

import tomllib
from pathlib import Path
from typing import Annotated, Any

import typer

from ncmeasure.errors import ConfigError

ControllersDir = Annotated[
    list[Path] | None,
    typer.Option(
        "--controllers-dir",
        help="Folder of your own controller definitions "
        "(<name>.toml), searched before the built-in ones.",
        show_default=False,
    ),
]
TemplatesDir = Annotated[
    list[Path] | None,
    typer.Option(
        "--templates-dir",
        help="Folder of your own templates (<dialect>/main.j2, "
        "sub.j2), searched before the built-in ones.",
        show_default=False,
    ),
]

PublishOption = Annotated[
    str | None,
    typer.Option(
        "--publish",
        metavar="URL",
        help="After storing, publish the machine's axis summaries to this MQTT broker: "
        "mqtt://[USER@]HOST[:PORT][/PREFIX] or mqtts://... (password: "
        "$NCMEASURE_MQTT_PASSWORD; docs/shop-floor.md). Nothing is sent without it.",
        show_default=False,
    ),
]

StoreOption = Annotated[
    str | None,
    typer.Option(
        "--store",
        metavar="URL",
        help="The store: sqlite:///FILE, postgresql://USER@HOST/DB, or a file path "
        "(default: $NCMEASURE_STORE, else ~/.local/share/ncmeasure/fleet.db).",
        show_default=False,
    ),
]

MeasuredAtOption = Annotated[
    str | None,
    typer.Option(
        "--measured-at",
        metavar="ISO8601",
        help="When the machine was measured, e.g. 2024-03-05T14:22:10+01:00 (a time without "
        "a zone is UTC; a date alone is its midnight UTC). Default: the recording's start; "
        "needed where that is unknown (an import whose data carry no date).",
        show_default=False,
    ),
]


def measured_at(text: str | None) -> str | None:
    """``--measured-at`` as ISO 8601 text in UTC (None: not given).

    Raises:
        ConfigError: The text is not an ISO 8601 date-time.
    """
    from ncmeasure.formats.identity import iso_utc, parse_utc

    return None if text is None else iso_utc(parse_utc(text, "--measured-at"))


WarningOption = Annotated[
    float | None,
    typer.Option(help="Warning limit of the change against the baseline, in % (default 20)."),
]
CriticalOption = Annotated[
    float | None,
    typer.Option(help="Critical limit of the change against the baseline, in % (default 40)."),
]


def pairs(values: list[str], option: str, key: str) -> dict[str, dict[str, Any]]:
    """``X=1`` options into per-axis settings ``{"X": {key: 1}}``."""
    from ncmeasure.config import parse_assignments

    form, example = "AXIS=NUMBER", f"{option} X=1"
    result: dict[str, dict[str, Any]] = {}
    for axis, value in parse_assignments(values, option, form=form, example=example):
        if not value.isdigit():
            raise ConfigError(f"{option} '{axis}={value}': expected {form}, e.g. {example}")
        result.setdefault(axis, {})[key] = int(value)
    return result


def settings(values: list[str], example: str = "--set sync_hz=500") -> dict[str, Any]:
    """``--set key=value`` options; values are read as TOML (numbers, true/false, strings)."""
    from ncmeasure.config import parse_assignments

    result: dict[str, Any] = {}
    for key, value in parse_assignments(values, "--set", example=example):
        try:
            result[key] = tomllib.loads(f"v = {value}")["v"]
        except (ValueError, RecursionError):  # not TOML (or beyond what Python reads): text
            result[key] = value
    return result


def axis_overrides(
    axis_set: list[str], node: list[str], unit: list[str], axes: list[str]
) -> dict[str, dict[str, Any]]:
    """The per-axis link settings of --axis-set, then --node and --unit over them.

    Raises:
        ConfigError: an item not of its form, or an axis the machine lacks.
    """
    result = axis_settings(axis_set, axes)
    for option, key, values in (("--node", "node_id", node), ("--unit", "unit_id", unit)):
        for axis, pair in pairs(values, option, key).items():
            result.setdefault(axis, {}).update(pair)
    unknown = set(result) - set(axes)
    if unknown:
        raise ConfigError(
            f"--node/--unit name axes the machine lacks: {', '.join(sorted(unknown))}"
        )
    return result


def axis_settings(values: list[str], axes: list[str]) -> dict[str, dict[str, Any]]:
    """``--axis-set [AXIS.]KEY=VALUE`` options into per-axis link settings.

    Without ``AXIS.`` a setting is for every axis; one for a named axis wins over it,
    whatever the order. Values are read as TOML (numbers, true/false, strings).

    Raises:
        ConfigError: an item not of that form, or an axis the machine lacks.
    """
    from ncmeasure.config import parse_assignments

    result: dict[str, dict[str, Any]] = {}
    form, example = "[AXIS.]KEY=VALUE", "--axis-set X.increments_per_rev=10000"
    found = parse_assignments(values, "--axis-set", form=form, example=example)
    found.sort(key=lambda pair: "." in pair[0])  # every axis first, then named ones
    for target, text in found:
        axis, dot, key = target.rpartition(".")
        if dot and axis not in axes:
            raise ConfigError(
                f"--axis-set '{target}={text}': the machine has no axis {axis} "
                f"(it has {', '.join(axes)})"
            )
        if not key:
            raise ConfigError(f"--axis-set '{target}={text}': expected {form}, e.g. {example}")
        value = settings([f"{key}={text}"], example=example)[key]
        for name in [axis] if dot else axes:
            result.setdefault(name, {})[key] = value
    return result


def given(**options: Any) -> dict[str, Any]:
    """The options given on the command line (those not None), by name."""
    return {key: value for key, value in options.items() if value is not None}


def limits(warning: float | None, critical: float | None) -> Any:
    """The limits of --warning/--critical; bad ones in one line, named as options."""
    from pydantic import ValidationError

    from ncmeasure.formats.comparison import Limits

    options = {"warning_percent": "--warning", "critical_percent": "--critical"}
    updates = given(warning_percent=warning, critical_percent=critical)
    try:
        return Limits.model_validate(updates)
    except ValidationError as exc:
        problems = []
        for error in exc.errors(include_url=False):
            text = str(error["msg"]).removeprefix("Value error, ")
            for field, option in options.items():
                text = text.replace(field, option)
            field = str(error["loc"][0]) if error["loc"] else ""
            problems.append(f"{options[field]} {updates[field]:g}: {text}" if field else text)
        raise ConfigError("; ".join(problems)) from exc
