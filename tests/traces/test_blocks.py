"""Reading many rows at once changes nothing: the block readers against the row-by-row ones.

The CSV export formats its rows in bulk, and the CSV, SINUMERIK CSV, TNCscope
and TwinCAT importers parse plain blocks of rows at once (``number_rows``),
handing anything else to the row-by-row reading they always had. Here every
trace is imported both ways (the block reader switched off by making
``number_rows`` find nothing plain), with blocks a few lines long, and the
recordings, reports and error messages must be the same.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from ncmeasure.errors import RecordingError
from ncmeasure.recording import Recording
from ncmeasure.traces import csv as csv_module
from ncmeasure.traces import import_trace, sinumerik_csv, tncscope, twincat_csv
from ncmeasure.traces import merge as merging
from ncmeasure.traces import text as trace_text
from ncmeasure.traces.csv import csv_rows
from ncmeasure.traces.job import ImportJob
from ncmeasure.traces.text import TextLines, number_rows

FIXTURES = Path(__file__).parent / "fixtures"
FIXTURE_TRACES = [
    ("twincat_per_channel.csv", "twincat-csv"),
    ("twincat_shared.csv", "twincat-csv"),
    ("tncscope.sco", "tncscope"),
    ("sinumerik_comma.csv", "sinumerik-csv"),
    ("sinumerik_semicolon.csv", "sinumerik-csv"),
    ("sinumerik_spaces.csv", "sinumerik-csv"),
    ("recording_export.csv", "csv"),
]
READERS = (csv_module, sinumerik_csv, tncscope, twincat_csv)

SINUMERIK_HEADER = (
    "time;/Nck/!SD/nckServoDataActCurr64 [u1; 1];/Nck/!SD/nckServoDataActPos1stEnc64 [u1; 1];"
    "/Nck/!SD/nckServoDataActVel1stEnc64 [u1; 1]\n"
)
#: Edge cases of the SINUMERIK CSV: leading rows before every signal has a value, empty
#: cells at the start, middle and end of rows, the invalid marker, decimal commas, a
#: quoted cell, a short row and a blank line (both read row by row).
SINUMERIK_EDGES = SINUMERIK_HEADER + "".join(
    [
        "0,000;1,5;;\n",
        "0,002;;10,25;\n",
        "0,004;1,75;10,5;100,125\n",
        "0,006;;;100,25\n",
        "0,008;9218868437227405312;10,75;\n",
        "0,010;2,5;;100,5\n",
        '0,012;"2,75";11;100,75\n',
        "0,014;3\n",
        "\n",
        "0,016;3,25;11,25;101\n",
        "0,018;3,5;;\n",
        "0,020;-0,0;11,5;1,5e2\n",
        "0,022;1e-05;11,75;\n",
    ]
)
TNC_EDGES = (
    "%[GLOBAL]\n%VERSION=test\n%\n"
    "%[CURVE 1]\n%CHANNELTYPE=v act.\n%AXISTYPE=X\n%DIMENSION=mm/min\n"
    "%COUNT=9\n%CYCLETIME=3000\n%\n"
    "%[CURVE 2]\n%CHANNELTYPE=i ist\n%AXISTYPE=X\n%DIMENSION=A\n%COUNT=4\n%CYCLETIME=6000\n%\n"
    "%[CURVE 3]\n%CHANNELTYPE=s actual\n%AXISTYPE=X\n%DIMENSION=mm\n%COUNT=9\n%CYCLETIME=3000\n%\n"
    "%[DATA]\n"
    + "".join(f"{3000 * k};{1250 + k},5;{k / 4:.2f};{k},25;\n" for k in range(4)).replace(".", ",")
    + "12000;1254,5;x;4,25;\n"
    + "".join(f"{3000 * k};{1250 + k},75;0;{k},5;\n" for k in range(5, 9))
)
TWINCAT_HEADER = (
    "Name\tt\r\nFile\tC:\\t.csv\r\nStarttime of export\t132959733843760000\r\n\r\n"
    "Name\tX_current_a\tName\tX_position_mm\r\nSampleTime[ms]\t1\tSampleTime[ms]\t2\r\n"
    "Unit\tA (Ampere)\tUnit\tmm (Millimeter)\r\n\r\n"
)
TWINCAT_EDGES = TWINCAT_HEADER + "".join(
    [f"{k}\t{k},5\t{2 * k}\t{k},25\r\n" for k in range(6)]
    + [f"{k}\t{k},5\t \t \r\n" for k in range(6, 12)]
    + ["EOF\r\n", "12\t1,5\t \t \r\n"]
)
GENERIC_EDGES = (
    "time_s,X_current_a,X_position_mm\n"
    "0.001,nan,1.5\n0.002,-0.0,-inf\n0.003,inf,1e-300\n0.004,+1.5,2.\n0.005,.5,1e5\n"
    "0.006,-0,0\n0.007,5e-324,1E+3\n0.008,0.1,0.2\n"
)


def _job(source: Path, target: Path) -> ImportJob:
    return ImportJob(source, target, "test", machine=None, axis_names=None, progress=None)


def _tiny_blocks(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(merging, "CHUNK_ROWS", 2)
    monkeypatch.setattr(merging, "MERGE_ROWS", 2)
    monkeypatch.setattr(csv_module, "_BLOCK_CHARS", 40)
    for module in (sinumerik_csv, tncscope, twincat_csv):
        monkeypatch.setattr(module, "_BLOCK_LINES", 3)


def _row_by_row(monkeypatch: pytest.MonkeyPatch) -> None:
    for module in READERS:
        monkeypatch.setattr(module, "number_rows", lambda *args, **kwargs: None)


def _import(source: Path, fmt: str, target: Path) -> tuple[Recording | str, list[str]]:
    """The recording and report of an import, or its error message."""
    try:
        result = import_trace(source, target, format=fmt)
    except RecordingError as exc:
        return str(exc), []
    return Recording.open(target), list(result.report)


def _both_ways(
    source: Path, fmt: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> tuple[tuple[Recording | str, list[str]], tuple[Recording | str, list[str]], int]:
    """The import in blocks, row by row, and the number of blocks read at once."""
    _tiny_blocks(monkeypatch)
    read: list[int] = []

    def counted(*args: Any, **kwargs: Any) -> Any:
        rows = number_rows(*args, **kwargs)
        read.extend([] if rows is None else [1])
        return rows

    with monkeypatch.context() as patch:
        for module in READERS:
            patch.setattr(module, "number_rows", counted)
        fast = _import(source, fmt, tmp_path / "fast")
    with monkeypatch.context() as patch:
        _row_by_row(patch)
        slow = _import(source, fmt, tmp_path / "slow")
    return fast, slow, len(read)


def _assert_same(
    fast: tuple[Recording | str, list[str]], slow: tuple[Recording | str, list[str]]
) -> None:
    (a, report_a), (b, report_b) = fast, slow
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
        return
    assert a.channel_names == b.channel_names
    assert np.array_equal(a.time_s.view(np.int64), b.time_s.view(np.int64))
    assert np.array_equal(a.values.view(np.int64), b.values.view(np.int64))
    assert report_a == report_b
    meta_a = json.loads((a.directory / "meta.json").read_text())
    meta_b = json.loads((b.directory / "meta.json").read_text())
    for meta in (meta_a, meta_b):
        meta.pop("end_utc", None)
    assert meta_a == meta_b


@pytest.mark.parametrize(("name", "fmt"), FIXTURE_TRACES)
def test_fixtures_read_in_blocks_as_row_by_row(
    name: str, fmt: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    fast, slow, _ = _both_ways(FIXTURES / name, fmt, tmp_path, monkeypatch)
    _assert_same(fast, slow)


@pytest.mark.parametrize(
    ("text", "fmt", "ending"),
    [
        (SINUMERIK_EDGES, "sinumerik-csv", ".csv"),
        (SINUMERIK_EDGES.replace("1e-05;11,75", "1e-05;11.75"), "sinumerik-csv", ".csv"),
        (SINUMERIK_EDGES.replace("0,010;", "0,008;"), "sinumerik-csv", ".csv"),
        (SINUMERIK_EDGES.replace("0,018;3,5", "0,018;3,5;;;"), "sinumerik-csv", ".csv"),
        (SINUMERIK_EDGES.replace("0,018;3,5", "0,018;abc"), "sinumerik-csv", ".csv"),
        (TNC_EDGES, "tncscope", ".sco"),
        (TNC_EDGES.replace("6000;", "3000;"), "tncscope", ".sco"),
        (TNC_EDGES.replace("21000;", "21000,5;"), "tncscope", ".sco"),
        (TWINCAT_EDGES, "twincat-csv", ".csv"),
        (TWINCAT_EDGES.replace("7\t7,5\t \t ", "7\t7,5\t \t3"), "twincat-csv", ".csv"),
        (TWINCAT_EDGES.replace("3\t3,5\t6", "3\t3,5\t4"), "twincat-csv", ".csv"),
        (TWINCAT_EDGES.replace("8\t8,5\t \t ", "8\t8,5\t  \t "), "twincat-csv", ".csv"),
        (TWINCAT_EDGES.replace("2\t2,5\t4", "2\t 2,5\t4"), "twincat-csv", ".csv"),
        (TWINCAT_EDGES.replace("9\t9,5\t \t \r", "9\t9,5\t \t 1\r"), "twincat-csv", ".csv"),
        (GENERIC_EDGES, "csv", ".csv"),
        (GENERIC_EDGES.replace("0.008,0.1", "0.008,0,1"), "csv", ".csv"),
        (GENERIC_EDGES.replace("0.007,", "0.0065,"), "csv", ".csv"),
    ],
)
def test_edge_cases_read_in_blocks_as_row_by_row(
    text: str, fmt: str, ending: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    source = tmp_path / f"trace{ending}"
    source.write_bytes(text.encode("utf-8"))
    fast, slow, blocks = _both_ways(source, fmt, tmp_path, monkeypatch)
    _assert_same(fast, slow)
    assert blocks  # some blocks were plain: both ways were taken


def test_the_edge_cases_are_read_as_written(tmp_path: Path) -> None:
    """The files above hold what they should: the comparison is not between two failures."""
    source = tmp_path / "trace.csv"
    source.write_text(SINUMERIK_EDGES, encoding="utf-8")
    recording = Recording.open(import_trace(source, tmp_path / "out").directory)
    # rows from the first with every signal on; the invalid marker is NaN, carried forward
    assert recording.time_s.tolist()[:3] == [0.004, 0.006, 0.008]
    assert np.isnan(recording.values[2, 0])
    assert recording.values[3, 0] == 2.5
    assert recording.values[-2:, 0].tolist() == [-0.0, 1e-05]


def test_rows_are_formatted_as_repr_writes_them() -> None:
    rng = np.random.default_rng(29)
    bits = rng.integers(0, 2**63, 40_000, dtype=np.int64).view(np.float64)
    special = [0.1, 1e16, 1e-5, 1e-4, 9.999e-5, -0.0, 0.0, np.nan, np.inf, -np.inf, 5e-324]
    values = np.concatenate([bits, -bits, special * 4, rng.normal(0, 100, 8_000)])
    rows = values[: len(values) // 4 * 4].reshape(-1, 4)
    expected = "".join(",".join(map(repr, row)) + "\n" for row in rows.tolist()).encode()
    assert csv_rows(rows) == expected
    assert csv_rows(rows[:0]) == b""


@pytest.mark.parametrize("width", [1, 2, 5])
def test_rows_with_small_values_and_infinities_are_formatted_as_repr(width: int) -> None:
    """Rows written with repr between the others (the first, the last, neighbours), and
    infinities in rows without a NaN."""
    rng = np.random.default_rng(width)
    rows = rng.normal(0, 100, (40, width))
    rows[[0, 7, 8, 20, 39], rng.integers(0, width, 5)] = [1e-5, -3e-7, 5e-324, 9.9e-5, 1e-300]
    rows[[3, 8, 30], -1] = [np.inf, -np.inf, np.inf]
    expected = "".join(",".join(map(repr, row)) + "\n" for row in rows.tolist()).encode()
    assert csv_rows(rows) == expected
    lines = expected.splitlines(keepends=True)
    assert csv_rows(rows[1:7]) == b"".join(lines[1:7])  # infinities, no NaN, no small value


@pytest.mark.parametrize(
    "block",
    [
        *(b"+1.5,2\n", b".5,2\n", b"5.,2\n", b"01,2\n", b"1, 2\n", b'"1",2\n', b"1,2\n\n3,4\n"),
        *(b"1,2,3\n", b"-0,2\n", b"2,-0\n", b"1e5e,2\n", b"1,null\n", b"-nan,1\n", b"NAN,1\n"),
        *(b"1,2,3\n4\n", b"1\n2,3,4\n", b"1,2\n3,-0", b"1,2\n,3\n", b"1,2\n3,4,\n", b"[1,2]\n"),
    ],
)
@pytest.mark.parametrize("empty", [False, True])
def test_number_rows_leaves_other_spellings_to_the_caller(block: bytes, empty: bool) -> None:
    assert number_rows(block, 2, empty=empty) is None


def test_number_rows_reads_what_float_reads() -> None:
    cells = [
        "0.1",
        "-0.0",
        "1e-300",
        "5e-324",
        "1E+5",
        "nan",
        "inf",
        "-inf",
        "123456789012345678901",
    ]
    cells += [
        "2.4703282292062328e-324",
        "0.1000000000000000055511151231257827021181583404541015625",
    ]
    block = "\n".join(f"{cell},{cell}" for cell in cells).encode()
    rows = number_rows(block, 2)
    assert rows is not None
    expected = np.array([[float(cell)] * 2 for cell in cells])
    same = (rows.view(np.int64) == expected.view(np.int64)) | (np.isnan(rows) & np.isnan(expected))
    assert same.all()
    empty = number_rows(b"1,,2,\n3,4,,\n", 4, empty=True)
    assert empty is not None
    assert np.isnan(empty).tolist() == [[False, True, False, True], [False, False, True, True]]
    assert number_rows(b",1\n", 2, empty=True) is None  # an empty first cell: the caller's
    assert number_rows(b"nan,1\n", 2, empty=True) is None  # NaN must mean an empty cell
    assert number_rows(b"1,NaN\n", 2, empty=True) is None
    assert number_rows(b"1,2\n3,Na\n", 2, empty=True) is None
    assert number_rows(b"1\n\n2\n", 1, empty=True) is None  # a blank line is no empty cell
    assert number_rows(b"\n1\n", 1, empty=True) is None
    assert number_rows(b"\n1,2\n", 2, empty=True) is None
    assert number_rows(b"1,2\n\n3,4\n", 2, empty=True) is None  # a blank line between rows
    assert number_rows(b"1,2\n,\n", 2, empty=True) is None  # a row of empty cells


@pytest.mark.parametrize(
    "data",
    [
        *(
            b"\xef\xbb\xbfa\r\nb\r\n\r\nc",
            b"a\rb\r\rc\r",
            b"a\nb\n",
            b"caf\xe9\nxxxxxx\n",
            b"a\r\r\nb",
        ),
        b"a\x0cb\r\nc\xe2\x80\xa8d\x1ce\nf\x0b",  # characters str.splitlines splits at
    ],
)
def test_lines_taken_at_once_are_the_lines_of_iteration(data: bytes, tmp_path: Path) -> None:
    source = tmp_path / "t.txt"
    source.write_bytes(data)
    with TextLines(source, _job(source, tmp_path / "a")) as lines:
        expected = list(lines)
    with TextLines(source, _job(source, tmp_path / "b")) as lines:
        first = next(iter(lines))
        taken = [first, *lines.take(2)]
        taken += lines.take(100)
        assert lines.take(5) == []
        assert lines.line_number == len(expected)
    assert taken == expected


@pytest.mark.parametrize(
    ("data", "plain"),
    [
        (b"h\n1,2\n3,4\n", b"1,2\n3,4\n"),
        (b"h\r\n1,2\r\n\r\n3,4", b"1,2\n\n3,4"),  # CRLF; the last line without its end
        (b"h\n1,2\r3,4\n", None),  # a bare CR
        (b"h\n1,2\r\r\n3,4\n", None),
        (b"h\n1,\xc3\xa9\n", None),  # not ASCII
        (b"h\n1,\x0c2\n3,4\n", b"1,\x0c2\n3,4\n"),  # one line, though str.splitlines splits it
    ],
)
def test_a_plain_block_gives_its_bytes_beside_its_lines(
    data: bytes, plain: bytes | None, tmp_path: Path
) -> None:
    source = tmp_path / "t.txt"
    source.write_bytes(data)
    with TextLines(source, _job(source, tmp_path / "a")) as lines:
        expected = list(lines)[1:]
    with TextLines(source, _job(source, tmp_path / "b")) as lines:
        next(iter(lines))
        block = lines.take_block(100)
        assert lines.line_number == 1 + len(expected) == 1 + len(block)
        assert block.plain == plain
        assert block.lines == expected
        if plain is not None:  # the text the lines give, but the last line end
            assert plain.rstrip(b"\n") == "\n".join(expected).encode()
        assert not lines.take_block(5)


@pytest.mark.parametrize(
    "data",
    [
        b"h\n1,2\n3,4\n5,6\n7,8\n",
        b"h\r\n1,2\r\n3,4\r\n\r\n7,8",  # CRLF, a blank line, no line end at the end
        b"h\n1,2\r3,4\n5,6\r\n7,8\r",  # bare CRs between LFs and CRLFs, one at the end
        b"h\r1,2\r3,4\r",  # CR only
        b"\xef\xbb\xbfh\n1,\xc3\xa9\n3,4\n\n",  # BOM, not ASCII, a blank line at the end
        b"h\n1,\xe9\n3,4\n5,6\n",  # not UTF-8: Windows-1252
    ],
)
@pytest.mark.parametrize("read_bytes", [3, 1 << 16])
def test_blocks_read_in_one_piece_are_the_lines_of_iteration(
    data: bytes, read_bytes: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Lines taken with none pending come from the file in one piece (read a few bytes or
    a block at a time): the same lines, numbers and plain bytes, from any line on."""
    monkeypatch.setattr(trace_text, "_READ_BYTES", read_bytes)
    source = tmp_path / "t.txt"
    source.write_bytes(data)
    with TextLines(source, _job(source, tmp_path / "a")) as lines:
        expected = list(lines)
    for skip in (0, 1):
        for count in (1, 2, 3, 100):
            with TextLines(source, _job(source, tmp_path / "b")) as lines:
                taken = [next(iter(lines))] if skip else []
                while block := lines.take_block(count):
                    assert len(block) == len(block.lines) <= count
                    if block.plain is not None:  # each line LF-ended, the file's last perhaps not
                        ended = "".join(line + "\n" for line in block.lines).encode()
                        assert block.plain in (ended, ended[:-1])
                    taken += block.lines
                    assert lines.line_number == len(taken)
                assert not lines.take_block(count)
            assert taken == expected, (skip, count)


def test_the_first_lines_are_never_plain(tmp_path: Path) -> None:
    """A block from the first line on may begin with a byte order mark: decoded, stripped."""
    source = tmp_path / "t.txt"
    source.write_bytes(b"1,2\n3,4\n")
    with TextLines(source, _job(source, tmp_path / "a")) as lines:
        block = lines.take_block(5)
        assert block.plain is None
        assert block.lines == ["1,2", "3,4"]


def test_a_bad_byte_in_a_block_names_its_line(tmp_path: Path) -> None:
    source = tmp_path / "t.txt"
    source.write_bytes(b"a\n" + b"x\n" * 70_000 + b"ok\xff\n")  # UTF-8 by the sniffed head
    with (
        TextLines(source, _job(source, tmp_path / "a")) as lines,
        pytest.raises(RecordingError, match=r"t\.txt:70002: not valid utf-8 text \(byte 3"),
    ):
        next(iter(lines))
        while lines.take(1000):
            pass


def test_read_bytes_constant_is_used(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Blocks and lines split across reads of a few bytes come out whole."""
    monkeypatch.setattr(trace_text, "_READ_BYTES", 3)
    source = tmp_path / "t.txt"
    source.write_bytes(b"ab\r\ncd\ref\n\ngh")
    with TextLines(source, _job(source, tmp_path / "a")) as lines:
        assert lines.take(10) == ["ab", "cd", "ef", "", "gh"]
