"""Parquet FCD with flat memory: SUMO writes its csv FCD into a named pipe and
behaviors/sumo/fcd_parquet.py writes parquet row groups from it as the run goes. SUMO's own parquet writer
kept the whole trace in memory until the end (~270 MB per simulated hour, docs/benchmarks.md); the
file must stay what SUMO's was: the same columns, types and (within float32) values.
"""

from __future__ import annotations

import errno
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from behaviors.errors import BehaveError
from behaviors.report.fcd_read import read_fcd
from behaviors.run.fcd_sealing import partial_path
from behaviors.run.populate import populate
from behaviors.run.populate_config import PopulateConfig
from behaviors.run.population import Population
from behaviors.sumo import fcd_parquet
from behaviors.sumo.fcd_parquet import METADATA_KEY, ParquetStream, column_type

RUN = {"overtakers": 2, "keepers": 2, "background": 8, "duration": 20.0, "seed": 4}
HEADER = "timestep_time;vehicle_id;vehicle_x;vehicle_y;vehicle_angle;vehicle_type;vehicle_speed;vehicle_lane"


def sumo_own_parquet(fcd: Path) -> None:
    """RUN with SUMO's own parquet writer, as populate wrote parquet before (Population directly)."""
    config = PopulateConfig(**RUN, fcd=fcd)
    population = Population(config)
    partial = partial_path(fcd)
    try:
        population.start(partial)
        for _ in range(round(config.duration / config.step_length)):
            population.step()
    finally:
        population.close()
    os.replace(partial, fcd)


@pytest.mark.sumo
def test_populates_parquet_is_sumos_own_columns_types_and_values(tmp_path):
    ours, sumo = tmp_path / "ours.parquet", tmp_path / "sumo.parquet"
    populate(PopulateConfig(**RUN, fcd=ours))
    sumo_own_parquet(sumo)
    a, b = pq.ParquetFile(ours), pq.ParquetFile(sumo)
    assert a.schema_arrow.equals(b.schema_arrow, check_metadata=False), (a.schema_arrow, b.schema_arrow)
    assert a.schema_arrow.field("vehicle_x").type == pa.float64()
    assert a.schema_arrow.field("vehicle_speed").type == pa.float32()
    settings = a.metadata.metadata[METADATA_KEY].decode()
    assert settings.startswith("behave populate: net=highway.net.xml overtakers=2 keepers=2")
    # SUMO's csv at 9 decimals: doubles to 5e-10, float32 to its last bit
    pd.testing.assert_frame_equal(a.read().to_pandas(), b.read().to_pandas(), rtol=1e-6, atol=1e-8)
    pd.testing.assert_frame_equal(read_fcd(ours), read_fcd(sumo), rtol=1e-6, atol=1e-8)


@pytest.mark.sumo
def test_parquet_is_written_as_the_run_goes(tmp_path, monkeypatch):
    """Row groups reach the disk during the run: SUMO's writer left its file empty until the end."""
    monkeypatch.setattr(fcd_parquet, "ROW_GROUP_ROWS", 100)
    monkeypatch.setattr(fcd_parquet, "PARSE_BYTES", 4096)
    fcd = tmp_path / "run.parquet"
    sizes: dict[float, int] = {}

    def on_step(simulated_s: float) -> None:
        if round(simulated_s, 3) in (5.0, 15.0):
            time.sleep(0.5)  # the reader's turn
            (partial,) = (p for p in tmp_path.glob(".run.parquet.*.tmp.parquet") if p.is_file())
            sizes[round(simulated_s, 3)] = partial.stat().st_size

    populate(PopulateConfig(**RUN, fcd=fcd), on_step=on_step)
    rows = pq.ParquetFile(fcd).metadata.num_rows
    assert rows > 900  # 12 cars, 100 steps
    assert pq.ParquetFile(fcd).metadata.num_row_groups >= rows // 200
    assert sizes[15.0] > sizes[5.0] > 5_000, sizes


def feed(stream: ParquetStream, *chunks: bytes) -> None:
    """Write to the pipe as SUMO does: open, write in pieces, close."""
    with open(stream.source, "wb") as csv:
        for chunk in chunks:
            csv.write(chunk)
            csv.flush()


ROWS = f"{HEADER}\n0.00;;;;;;;\n0.20;a;1.5;-2.25;90.00;car;3.125;e0_0\n0.20;b;2.0;1.0;90.00;car;0.0;e0_1\n"


@pytest.mark.parametrize("piped", [True, False])
def test_the_stream_keeps_empty_steps_drops_a_cut_row_and_renames_geo(tmp_path, monkeypatch, piped):
    if not piped:  # a system without named pipes: SUMO writes a file, converted at the end
        monkeypatch.delattr(os, "mkfifo")
    target = tmp_path / "t.parquet"
    stream = ParquetStream(target, geo=True)
    assert stream.piped == piped
    try:
        feed(stream, ROWS[:30].encode(), ROWS[30:].encode(), b"0.40;a;1.9;-2.2")  # SUMO stopped mid-row
        stream.finish("behave populate: test")
    finally:
        stream.close()
    table = pq.read_table(target)
    assert table.schema.names[2:4] == ["vehicle_lon", "vehicle_lat"]
    assert [table.schema.field(n).type for n in ("timestep_time", "vehicle_lon", "vehicle_speed")] == [
        pa.float64(), pa.float64(), pa.float32(),
    ]  # fmt: skip
    assert table.column("timestep_time").to_pylist() == [0.0, 0.2, 0.2]  # the cut row left out
    assert table.column("vehicle_id").to_pylist() == [None, "a", "b"]  # an empty step: nulls, as SUMO's
    assert pq.ParquetFile(target).metadata.metadata[METADATA_KEY] == b"behave populate: test"
    assert stream.cut_row and stream.last_time == 0.2 and stream.rows == 3
    assert not stream.work.exists()


def test_a_stream_sumo_never_opened_ends_at_once(tmp_path):
    stream = ParquetStream(tmp_path / "t.parquet")
    start = time.monotonic()
    with pytest.raises(BehaveError, match="SUMO wrote no FCD"):
        stream.finish("x")
    stream.close()
    assert time.monotonic() - start < 10 and not stream.work.exists()


WRITER_HOLDING_THE_GIL = """
import ctypes, sys
from pathlib import Path
from behaviors.sumo.fcd_parquet import ParquetStream
stream = ParquetStream(Path(sys.argv[1]))
fd = open(stream.source, "wb", buffering=0)
data = (sys.argv[2] + "\\n" + "1.00;a;1.5;-2.25;90.00;car;3.125;e0_0\\n" * 400_000).encode()  # 16 MB
libc = ctypes.PyDLL(None)  # PyDLL: the call keeps the GIL, as libsumo's do while SUMO writes
while data:
    done = libc.write(fd.fileno(), data, len(data))
    data = data[done:]
fd.close()
stream.finish("x")
stream.close()
print(stream.rows)
"""


def test_sumo_writing_while_it_holds_the_gil_is_never_left_waiting(tmp_path):
    """libsumo holds Python's GIL while SUMO writes its outputs: a reader thread of the same process
    could not empty the pipe, and SUMO stood still on it for good (a soak run did)."""
    done = subprocess.run([sys.executable, "-c", WRITER_HOLDING_THE_GIL, str(tmp_path / "t.parquet"), HEADER],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["400000"]


@pytest.fixture
def small_disk(tmpfs: Callable[[int], Path]) -> Path:
    """A 64 kB file system of its own."""
    return tmpfs(64)


def test_a_full_disk_under_the_parquet_is_reported_and_never_blocks_sumo(small_disk):
    """The reader keeps emptying the pipe after a failed write (SUMO would wait on a full pipe for
    good), and finish says why the file was not written."""
    stream = ParquetStream(small_disk / "t.parquet", final=small_disk / "run.parquet")
    rows = b"".join(b"%d.00;veh%d;1.5;-2.25;90.00;car;3.125;e0_0\n" % (i, i) for i in range(200_000))
    writer = threading.Thread(target=feed, args=(stream, f"{HEADER}\n".encode(), rows))  # 8 MB
    writer.start()
    writer.join(120)
    assert not writer.is_alive()
    with pytest.raises(BehaveError, match=r"run\.parquet not written: No space left on device"):
        stream.finish("x")
    stream.close()


def test_a_failed_write_drops_the_rest_of_the_csv(tmp_path, monkeypatch):
    convert = fcd_parquet.CsvToParquet(tmp_path / "t.parquet", geo=False, row_group_rows=2, parse_bytes=1)

    def no_space() -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(convert, "_write", no_space)
    convert.feed(ROWS.encode())
    convert.feed(ROWS.split("\n", 1)[1].encode())
    convert.end()
    assert convert.report()["error"] == "No space left on device" and convert.rows == 0


def test_column_types_follow_sumos_parquet():
    assert [column_type(n) for n in ("timestep_time", "vehicle_y", "vehicle_odometer", "vehicle_lane")] == [
        pa.float64(), pa.float64(), pa.float32(), pa.string(),
    ]  # fmt: skip
