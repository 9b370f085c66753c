"""docs/shop-floor.md against the code: the MQTT message, field by field."""

from __future__ import annotations

import json
import re
from pathlib import Path

from ncmeasure.publish import axis_summaries
from ncmeasure.store import open_store
from ncmeasure.store.overview import fleet_overview

DOC = Path(__file__).parents[2] / "docs" / "shop-floor.md"


def _section(title: str) -> str:
    text = DOC.read_text(encoding="utf-8")
    start = text.index(f"\n### {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end > 0 else None]


def test_the_message_is_documented_field_by_field(store_with_machine: str) -> None:
    with open_store(store_with_machine) as store:
        message = axis_summaries(fleet_overview(store))[0].message()
    section = _section("The message")
    example = json.loads(re.search(r"```json\n(.*?)```", section, re.S)[1])  # type: ignore[index]
    table = re.findall(r"^\| `(\w+)` \|", section, re.M)
    assert list(example) == list(message)
    assert table == list(message)
