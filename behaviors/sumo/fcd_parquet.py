"""Parquet FCD whose memory stays flat however long the run: SUMO writes its csv FCD into a named pipe,
and a process of its own turns it into parquet row groups as the run goes.

SUMO 1.28's own parquet writer keeps the trace in memory until the run ends (one row group; ~260 MB
per simulated hour at first with 100 cars, docs/benchmarks.md), while its csv is written as it goes.
Here SUMO writes csv, at `PRECISION` decimals (its csv and xml round to 2; its parquet keeps every
value as it is: x, y as doubles, the other numbers as float32), and the parquet written from it has
SUMO's parquet's columns, types and, to a few 1e-10, values. Memory: one row group of
`ROW_GROUP_ROWS` rows at most, whatever the run's length.

The reader is a process, not a thread: libsumo holds Python's GIL while SUMO writes, so a thread of
this process could not empty the pipe SUMO waits on (docs/benchmarks.md). The process follows its
parent: it leaves when the parent's end of its stdin closes.

Where the OS has no named pipes (or the folder takes none) SUMO writes a temporary csv file beside
the target and it is converted in this process when SUMO has closed it: flat memory still, and the
csv's disk space until then.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import select
import shutil
import subprocess
import sys
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from behaviors.errors import BehaveError
from behaviors.files import temp_dir

if TYPE_CHECKING:
    import pyarrow as pa
    import pyarrow.parquet as pq

PRECISION = 9
"""Decimals of the csv SUMO writes for the parquet: float32 keeps 7 significant digits, and x, y
(doubles in SUMO's parquet) keep nanometres. SUMO's `--precision` applies to each of its outputs."""
ROW_GROUP_ROWS = 1 << 16
"""Rows per parquet row group (~8 MB in memory, ~3 MB on disk): the most the reader holds. The reader
process stays near 100 MB (50 of them pyarrow's code); larger groups make it grow (docs/benchmarks.md)."""
READ_BYTES = 1 << 22
"""Bytes of csv read at a time (a pipe gives what it holds: 1 MB at most)."""
PARSE_BYTES = 1 << 22
"""Bytes of csv parsed at a time, into one table."""
PIPE_BYTES = 1 << 20
"""The pipe's buffer on Linux (64 kB by default): SUMO waits less on a reader busy writing a row group."""
DOUBLE_COLUMNS = ("time", "x", "y")
"""Columns SUMO's parquet writes as doubles (by name after the element prefix: timestep_time,
vehicle_x, ...; lon/lat are x/y in SUMO's geo output); its other numbers are float32."""
TEXT_COLUMNS = ("id", "type", "lane", "edge")
GEO_NAMES = {"vehicle_x": "vehicle_lon", "vehicle_y": "vehicle_lat"}
"""SUMO's geo output keeps calling lon/lat x/y; behave's files name them (as fcd_whole._geo_names)."""
METADATA_KEY = b"behave"
"""The parquet file's key-value metadata behave writes: the run's settings, as XML FCD's header."""
SUMO_CLOSED = b"closed\n"
NOTHING_WRITTEN = "SUMO wrote no FCD"
"""Parent to reader: SUMO closed its outputs, what is in the pipe is all there is."""


def precision_options() -> list[str]:
    """SUMO options that write every decimal the parquet keeps."""
    return ["--precision", str(PRECISION), "--precision.geo", str(PRECISION)]


def column_type(name: str) -> pa.DataType:
    """The arrow type SUMO's parquet writer gives an FCD column (tests/sumo/test_fcd_parquet.py checks)."""
    import pyarrow as pa

    attribute = name.split("_", 1)[-1]
    if attribute in DOUBLE_COLUMNS:
        return pa.float64()
    return pa.string() if attribute in TEXT_COLUMNS else pa.float32()


class ParquetStream:
    """SUMO's csv FCD, written to `source`, as parquet at `target`.

    Make it before SUMO starts, give SUMO `source` with `precision_options()`, and once SUMO has closed
    its outputs call `wait` (every whole row in the parquet: `last_time`, `rows`) and `finish` (its
    footer, with the run's settings), and always `close`. `geo`: name the coordinates lon/lat. `final`:
    the file the parquet becomes, as messages name it.
    """

    def __init__(self, target: Path, *, geo: bool = False, final: Path | None = None) -> None:
        self.target = Path(target)
        self.final = Path(final or target)
        self.geo = geo
        self.work = temp_dir(self.target)  # beside the target, removed by a later run if this one dies
        self.source = self.work / "fcd.csv"  # SUMO picks csv by the suffix
        self.rows = 0
        self.last_time: float | None = None  # of the last row written
        self.cut_row = False  # the csv ended inside a row (dropped)
        self.error: str | None = None
        self._state: dict[str, Any] | None = None  # what the reader reported at the csv's end
        self._local: CsvToParquet | None = None
        self._reader: subprocess.Popen[bytes] | None = None
        try:
            os.mkfifo(self.source)
        except (AttributeError, OSError):  # no named pipes here: a plain file, converted at the end
            return
        command = [sys.executable, "-m", "behaviors.sumo.fcd_parquet", str(self.source), str(self.target),
                   str(ROW_GROUP_ROWS), str(PARSE_BYTES)]  # fmt: skip
        self._log = self.work / "reader.log"  # a file: a reader never waits on a full stderr pipe
        with open(self._log, "wb") as log:
            self._reader = subprocess.Popen(
                [*command, *(["--geo"] if geo else [])],
                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log,
                start_new_session=True,  # Ctrl-C is populate's to handle: the reader finishes the file
            )  # fmt: skip

    @property
    def piped(self) -> bool:
        return self._reader is not None

    def wait(self) -> None:
        """Once SUMO closed the csv: every whole row of it in the parquet's row groups."""
        if self._state is not None:
            return
        if self._reader is None:
            self._local = CsvToParquet(self.target, self.geo, ROW_GROUP_ROWS, PARSE_BYTES)
            with contextlib.suppress(FileNotFoundError), open(self.source, "rb") as csv:
                self._local.convert(csv)
            self._state = self._local.report()
        else:
            assert self._reader.stdin is not None and self._reader.stdout is not None
            with contextlib.suppress(BrokenPipeError):
                self._reader.stdin.write(SUMO_CLOSED)
                self._reader.stdin.flush()
            self._state = self._answer()
        self.rows, self.last_time = self._state["rows"], self._state["last_time"]
        self.cut_row, self.error = self._state["cut_row"], self._state["error"]

    def finish(self, metadata: str) -> None:
        """Once SUMO closed the csv: the parquet's last row group and footer, with `metadata` under
        METADATA_KEY. A BehaveError if the csv held no header or a write failed (a full disk)."""
        self.wait()
        if self.error is None and not (self._state or {}).get("header"):
            self.error = NOTHING_WRITTEN
        if self.error is None:
            if self._local is not None:
                self.error = self._local.close(metadata)
            else:
                assert self._reader is not None and self._reader.stdin is not None
                with contextlib.suppress(BrokenPipeError):
                    self._reader.stdin.write(json.dumps(metadata).encode() + b"\n")
                    self._reader.stdin.close()
                self.error = self._answer()["error"]
        if self.error == NOTHING_WRITTEN:
            raise BehaveError(f"{NOTHING_WRITTEN}, {self.final} not written")
        if self.error is not None:
            raise BehaveError(f"{self.final} not written: {self.error}")

    def close(self) -> None:
        """End the reader (at once where `finish` was not reached) and remove the pipe; the parquet
        stays as it is (the caller removes an unfinished one)."""
        if self._reader is not None:
            if self._reader.poll() is None:
                self._reader.kill()
            self._reader.wait()
            for pipe in (self._reader.stdin, self._reader.stdout):
                with contextlib.suppress(OSError, ValueError):  # closed already
                    pipe.close()  # type: ignore[union-attr]
        if self._local is not None:
            self._local.close(None)
        shutil.rmtree(self.work, ignore_errors=True)

    def _answer(self) -> dict[str, Any]:
        """The reader's next report, one JSON line; its stderr if it died instead."""
        assert self._reader is not None and self._reader.stdout is not None
        line = self._reader.stdout.readline()
        if line:
            answer: dict[str, Any] = json.loads(line)
            return answer
        self._reader.wait()
        said = self._log.read_text(errors="replace").strip().splitlines()
        error = f"the parquet writer stopped ({said[-1] if said else f'exit code {self._reader.returncode}'})"
        return {"rows": 0, "last_time": None, "cut_row": False, "error": error, "header": False}


class CsvToParquet:
    """SUMO's csv FCD, read in blocks, into parquet row groups at `target` (the reader's work)."""

    def __init__(self, target: Path, geo: bool, row_group_rows: int, parse_bytes: int) -> None:
        self.target = target
        self.geo = geo
        self.row_group_rows = row_group_rows
        self.parse_bytes = parse_bytes
        self.rows = 0
        self.last_time: float | None = None
        self.cut_row = False
        self.header = False
        self.error: str | None = None
        self._writer: pq.ParquetWriter | None = None
        self._names: list[str] = []
        self._batches: list[pa.Table] = []
        self._buffered = 0
        self._chunks: list[bytes] = []  # csv read, not parsed yet
        self._size = 0

    def convert(self, csv: IO[bytes]) -> None:
        """The whole of a csv file (or a blocking pipe) to its end."""
        while block := csv.read(READ_BYTES):
            self.feed(block)
        self.end()

    def feed(self, block: bytes) -> None:
        """More csv; whole rows are parsed, a row group written once `row_group_rows` are buffered. After
        a failed write (a full disk) the rest is read and dropped: SUMO must never wait on the pipe."""
        if self.error is not None:
            return
        try:
            self._feed(block)
        except Exception as exc:  # pyarrow's errors on a full disk are OSError subclasses or its own
            self.error = reason(exc)

    def end(self) -> None:
        """The csv ended: the last rows' row group; a last row without its newline (SUMO stopped inside
        it) is left out."""
        if self.error is not None:
            return
        try:
            self._feed(b"", final=True)
            if self._batches or (self.header and self._writer is None):  # a header without rows
                self._write()
        except Exception as exc:
            self.error = reason(exc)
        self.cut_row = self._size > 0

    def report(self) -> dict[str, Any]:
        return {"rows": self.rows, "last_time": self.last_time, "cut_row": self.cut_row,
                "error": self.error, "header": self.header}  # fmt: skip

    def close(self, metadata: str | None) -> str | None:
        """The footer, with `metadata` under METADATA_KEY (None: closed as it is); the error, if any."""
        writer, self._writer = self._writer, None
        if writer is None:
            return self.error
        try:
            if metadata is not None:
                writer.add_key_value_metadata({METADATA_KEY: metadata.encode()})
            writer.close()
        except Exception as exc:  # pyarrow's own on a full disk
            self.error = self.error or reason(exc)
        return self.error

    def _feed(self, block: bytes, final: bool = False) -> None:
        """Blocks are kept until `parse_bytes` are there (SUMO writes a step at a time: thousands of small
        tables would fragment the reader's memory), then their whole rows parsed."""
        self._chunks.append(block)
        self._size += len(block)
        if self._size < self.parse_bytes and not final:
            return
        data = b"".join(self._chunks)
        self._chunks, self._size = [], 0
        if not self.header:
            if b"\n" not in data:
                self._chunks, self._size = [data], len(data)
                return
            line, data = data.split(b"\n", 1)
            self._names = line.decode().rstrip("\r").split(";")
            self.header = True
        end = data.rfind(b"\n") + 1
        if end < len(data):
            self._chunks, self._size = [data[end:]], len(data) - end
        if end:
            self._batches.append(self._parse(data[:end]))
            self._buffered += self._batches[-1].num_rows
        if self._buffered >= self.row_group_rows:
            self._write()

    def _parse(self, rows: bytes) -> pa.Table:
        import pyarrow as pa
        import pyarrow.csv as pacsv

        types = {name: column_type(name) for name in self._names}
        if not rows:
            return pa.table({name: pa.array([], kind) for name, kind in types.items()})
        return pacsv.read_csv(
            pa.py_buffer(rows),
            read_options=pacsv.ReadOptions(
                column_names=self._names, use_threads=False, block_size=len(rows) + 1
            ),
            parse_options=pacsv.ParseOptions(delimiter=";", quote_char=False),
            convert_options=pacsv.ConvertOptions(column_types=types, strings_can_be_null=True),
        )

    def _write(self) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        names = [GEO_NAMES.get(n, n) if self.geo else n for n in self._names]
        table = pa.concat_tables(self._batches or [self._parse(b"")]).rename_columns(names)
        self._batches, self._buffered = [], 0
        if self._writer is None:
            self._writer = pq.ParquetWriter(self.target, table.schema)
        self._writer.write_table(table, row_group_size=max(len(table), 1))
        self.rows += len(table)
        if len(table):
            self.last_time = table.column(0)[-1].as_py()


def reason(exc: BaseException) -> str:
    """An error as its reason: ENOSPC as the OS says it, whatever type pyarrow gave it."""
    if isinstance(exc, OSError) and exc.errno is not None:
        return os.strerror(exc.errno)
    text = " ".join(str(exc).split()) or type(exc).__name__
    return os.strerror(errno.ENOSPC) if "No space left" in text else text


def read_pipe(source: Path, target: Path, row_group_rows: int, parse_bytes: int, geo: bool) -> None:
    """The reader process: the pipe into row groups until SUMO has closed it and the parent says so
    (a pipe SUMO never opened ends there too), a report line, then the parent's metadata line, the
    footer, a last report line. The parent gone (its end of stdin closed) ends it at once."""
    convert = CsvToParquet(target, geo, row_group_rows, parse_bytes)
    fifo = os.open(source, os.O_RDONLY | os.O_NONBLOCK)  # a reader now: SUMO's open() goes through
    if sys.platform.startswith("linux"):
        import fcntl

        with contextlib.suppress(OSError):  # above /proc/sys/fs/pipe-max-size: the default
            fcntl.fcntl(fifo, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
    control = sys.stdin.buffer.fileno()
    poller = select.poll()
    poller.register(fifo, select.POLLIN)
    poller.register(control, select.POLLIN)
    told = closed = False  # the parent said SUMO closed the pipe; SUMO closed it
    while not (told or closed):
        for fd, _ in poller.poll(1000):
            if fd == control:
                if os.read(control, 64) != SUMO_CLOSED:
                    sys.exit(1)  # the parent is gone
                told = True
            elif not _drain(fifo, convert):  # SUMO closed its end
                closed = True
    while _drain(fifo, convert):  # what SUMO left in the pipe (non-blocking: ends at once if empty)
        pass
    if not told and os.read(control, 64) != SUMO_CLOSED:  # the parent's word before the report
        sys.exit(1)
    convert.end()
    _say(convert.report())
    line = sys.stdin.buffer.readline()
    if not line:
        sys.exit(1)
    _say({"error": convert.close(json.loads(line))})


def _drain(fifo: int, convert: CsvToParquet) -> bool:
    """Read what the pipe holds into `convert`; False once it is at its end (no writer, empty)."""
    while True:
        try:
            block = os.read(fifo, READ_BYTES)
        except BlockingIOError:  # empty, SUMO still writing
            return True
        if not block:
            return False
        convert.feed(block)


def _say(report: dict[str, Any]) -> None:
    sys.stdout.write(json.dumps(report) + "\n")
    sys.stdout.flush()


if __name__ == "__main__":
    read_pipe(
        Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), "--geo" in sys.argv[5:]
    )
