"""IPG export keeps each vehicle's rows together under its id; GPX times are ISO dates.
A small hand-written FCD: no SUMO run."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from datetime import datetime, timezone
from pathlib import Path

from helpers import behave

from behaviors.report.export import GPX_NAMESPACE, export_fcd

TIMES = (0.0, 0.2, 0.4)


def fcd(path: Path, *, geo: bool) -> Path:
    """Two vehicles side by side for three steps (lon/lat near 4.5, 0.0 with `geo`)."""
    scale = 1e-5 if geo else 1.0
    steps = []
    for k, t in enumerate(TIMES):
        cars = "".join(
            f'<vehicle id="{vid}" x="{(4.5 / scale if geo else 0) + 10 * k + lane:.2f}" '
            f'y="{3.5 * lane:.2f}" angle="90.00" type="car" speed="10.00" pos="{10 * k:.2f}" '
            f'lane="e_{lane}"/>'
            for lane, vid in enumerate(("a", "b"))
        )
        steps.append(f'<timestep time="{t:.2f}">{cars}</timestep>')
    body = "".join(steps)
    if geo:  # lon/lat in x/y, as SUMO's geo output writes them
        root = ET.fromstring(f"<fcd-export>{body}</fcd-export>")
        for v in root.iter("vehicle"):
            v.set("x", f"{float(v.get('x')) * scale:.7f}")
            v.set("y", f"{float(v.get('y')) * scale:.7f}")
        body = "".join(ET.tostring(step, encoding="unicode") for step in root)
    header = "<!-- behave populate: net=n.net.xml geo=true -->\n" if geo else ""
    path.write_text(f'<?xml version="1.0" encoding="UTF-8"?>\n{header}<fcd-export>{body}</fcd-export>\n')
    return path


def test_ipg_gives_each_vehicle_its_block_under_its_id(tmp_path: Path) -> None:
    [out] = export_fcd(fcd(tmp_path / "f.xml", geo=False), "ipg", net=None, out=tmp_path / "t.ipg")
    blocks = out.read_text().split("# vehicle ")[1:]
    assert [block.splitlines()[0] for block in blocks] == ["a", "b"]  # every row under an id
    for block in blocks:
        header, *rows = block.splitlines()[1:]
        assert header == "# Time tx ty tz rx ry rz"
        assert [float(row.split()[0]) for row in rows] == list(TIMES)  # its own rows, by time
    assert blocks[1].splitlines()[2] == "0.0 1.0 3.5 0.0 90.0 0 0"


def test_gpx_times_are_iso_dates_from_the_start_given(tmp_path: Path) -> None:
    source = fcd(tmp_path / "geo.xml", geo=True)
    for start, first in ((None, datetime(1970, 1, 1, tzinfo=timezone.utc)),
                         ("2024-05-06T08:00:00Z", datetime(2024, 5, 6, 8, tzinfo=timezone.utc))):  # fmt: skip
        out = tmp_path / f"{start is None}.gpx"
        done = behave("export", str(source), "--to", "gpx", "--out", str(out),
                      *(("--start-time", start) if start else ()))  # fmt: skip
        assert done.returncode == 0, done.stderr
        texts = [e.text or "" for e in ET.parse(out).getroot().iter(f"{{{GPX_NAMESPACE}}}time")]
        assert len(texts) == 6 and all(t.endswith("Z") for t in texts)
        moments = [datetime.fromisoformat(t.replace("Z", "+00:00")) for t in texts]
        assert [(m - first).total_seconds() for m in moments[:3]] == list(TIMES)
    assert texts[1] == "2024-05-06T08:00:00.200Z"
    done = behave(
        "export", str(source), "--to", "gpx", "--out", str(tmp_path / "x.gpx"), "--start-time", "noon"
    )
    assert done.returncode == 2 and "--start-time takes an ISO 8601 date" in done.stderr
