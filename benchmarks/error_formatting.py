"""Formatting many machine-file problems, beside pydantic listing them.

A machine file with n misspelt keys gives n problems. ncmeasure turns them into
``location: message`` lines (``config.format_validation_error``); the time per
problem should stay flat as n grows (linear), like pydantic's own listing of
the same errors, which is the baseline.

Run: python benchmarks/error_formatting.py
"""

from __future__ import annotations

import time
import tomllib

from pydantic import ValidationError

from ncmeasure.config import MachineConfig, format_validation_error
from ncmeasure.examples import example_machine


def _error(count: int) -> ValidationError:
    data = tomllib.loads(example_machine("linuxcnc"))
    data["measurement"].update({f"margin_mn{n}": 5.0 for n in range(count)})
    try:
        MachineConfig.model_validate(data)
    except ValidationError as exc:
        return exc
    raise AssertionError("the file was valid")


def main() -> None:
    print(f"{'problems':>9} {'pydantic µs/problem':>20} {'ncmeasure µs/problem':>21}")
    for count in (1_000, 10_000, 100_000):
        exc = _error(count)
        start = time.perf_counter()
        exc.errors(include_url=False)
        listed = time.perf_counter() - start
        start = time.perf_counter()
        lines = format_validation_error(exc)
        formatted = time.perf_counter() - start
        assert len(lines) == count
        print(f"{count:>9} {listed / count * 1e6:>20.2f} {formatted / count * 1e6:>21.2f}")


if __name__ == "__main__":
    main()
