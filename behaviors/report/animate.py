"""Top-down animation of an FCD file (`behave animate`): the road from the net, every vehicle as a
box of its vType's size (behaviors/sumo/vtypes.py), learned cars coloured by behaviour as `behave plot`
colours them and SUMO's by class, a time stamp per frame.

One frame per `every` seconds of FCD time, showing each vehicle's last record at or before that
instant. A road so long that a car would be a speck in the whole view (MIN_CAR_PX) is followed: the
view, AUTO_WINDOW_M wide, stays on a learned car (another once it leaves). `follow` draws while its
vehicle is in the FCD. GIF goes through Pillow (frames kept as 8-bit palette images, a quarter of RGBA's
memory); MP4 through ffmpeg, where matplotlib finds one. Written to a temp file and renamed.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from behaviors.errors import BehaveError
from behaviors.files import atomic_path, check_output_path

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

ANIMATION_SUFFIXES = (".gif", ".mp4")
CAR_LENGTH, CAR_WIDTH = 5.0, 1.8
"""m: a passenger car's size (SUMO's default, behave's cars'); other vehicles are drawn at their own."""
FIGURE_WIDTH_IN, DPI = 8.0, 100
MIN_CAR_PX = 4.0
"""Pixels a car's length must take in the whole view, or the view follows the action (at 800 pixels a
4.5 km road draws cars of 0.9 px, specks)."""
AUTO_WINDOW_M = 250.0
"""m: the width of the view that follows the action (a car 16 px long at 800 px)."""
CLASS_STYLES = {  # SUMO's vehicles by vClass -> (legend label, colour); other classes are SUMO cars
    "truck": ("SUMO lorry", "tab:brown"), "trailer": ("SUMO lorry", "tab:brown"),
    "bus": ("SUMO bus or coach", "tab:purple"), "coach": ("SUMO bus or coach", "tab:purple"),
    "delivery": ("SUMO van", "tab:olive"), "motorcycle": ("SUMO two-wheeler", "tab:pink"),
    "moped": ("SUMO two-wheeler", "tab:pink"), "bicycle": ("SUMO two-wheeler", "tab:pink"),
}  # fmt: skip
MARGIN_M = 10.0
NET_NAME = re.compile(r"<!-- behave populate: net=(\S+)")
SUMO_NET_FILE = re.compile(r'<net-file value="([^"]+)"')
ROAD_COLOUR, MARKING_COLOUR = "#d9d9d9", "#555555"


@dataclass(frozen=True)
class AnimateOptions:
    every: float = 1.0  # FCD seconds per frame
    fps: int = 10  # frames per second of playback
    follow: str | None = None  # vehicle id the view follows
    window: float = 200.0  # m: the width of the followed view
    net: Path | None = None  # None: the net the FCD names, if it can be found
    geo: bool = False  # the FCD holds lon/lat
    whole: bool = False  # the whole road however long (else a long road is followed: MIN_CAR_PX)
    sumocfg: Path | None = None  # whose route and additional files define the vTypes (sizes, classes)

    def validate(self) -> None:
        for name in ("every", "fps", "window"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise BehaveError(f"--{name} must be a finite number > 0, got {value}")


def check_animation_output(out: Path) -> None:
    """BehaveError now, before the FCD is read, if `out` cannot be written as an animation."""
    suffix = out.suffix.lower()
    if suffix not in ANIMATION_SUFFIXES:
        raise BehaveError(f"animation output must end in {' or '.join(ANIMATION_SUFFIXES)}: {out}")
    if suffix == ".mp4" and not ffmpeg_found():
        raise BehaveError(
            f"cannot write {out}: MP4 needs ffmpeg on PATH or the video extra "
            "(pip install 'behave-traffic[video]'); or write a .gif"
        )
    check_output_path(out)


def ffmpeg_found() -> bool:
    """Whether matplotlib can run ffmpeg: the one on PATH, else the binary the imageio-ffmpeg wheel
    (the `video` extra) carries, which needs no system package."""
    import matplotlib
    from matplotlib.animation import FFMpegWriter

    if FFMpegWriter.isAvailable():
        return True
    try:
        import imageio_ffmpeg
    except ImportError:
        return False
    matplotlib.rcParams["animation.ffmpeg_path"] = imageio_ffmpeg.get_ffmpeg_exe()
    return FFMpegWriter.isAvailable()


def frame_times(first: float, last: float, every: float) -> np.ndarray:
    """The instants drawn: `first`, then one per `every` seconds up to `last` (a record's rounding
    does not drop the last frame)."""
    count = math.floor((last - first) / every + 1e-6) + 1
    return first + every * np.arange(max(count, 1))


def step_at(step_times: np.ndarray, instants: np.ndarray) -> np.ndarray:
    """Index of the last FCD step at or before each instant (steps sorted, instants >= the first)."""
    return np.searchsorted(step_times, instants + 1e-6, side="right") - 1


def time_label(t: float, every: float) -> str:
    """`t = 12.4 s`, with as many decimals as `every` needs, so no two frames read the same."""
    decimals = max(0, math.ceil(-math.log10(every) - 1e-9))
    return f"t = {t:.{decimals}f} s"


def car_boxes(
    x: np.ndarray,
    y: np.ndarray,
    angle: np.ndarray,
    length: float | np.ndarray,
    width: float | np.ndarray,
    scale: tuple[float, float] = (1.0, 1.0),
) -> np.ndarray:
    """[N, 4, 2] corners of each vehicle from SUMO's front-bumper position and angle (degrees clockwise
    from north), `length` and `width` one for all or [N]; `scale` turns the metre offsets into the
    coordinates' units (degrees of lon/lat)."""
    heading = np.radians(angle)
    ahead = np.stack([np.sin(heading), np.cos(heading)], axis=1)
    right = np.stack([np.cos(heading), -np.sin(heading)], axis=1)
    length, width = np.asarray(length, float)[..., None], np.asarray(width, float)[..., None]
    half = width / 2 * right
    offsets = np.stack([half, -half, -half - length * ahead, half - length * ahead], axis=1)
    return np.stack([x, y], axis=1)[:, None, :] + offsets * np.asarray(scale)


def follow_centres(times: np.ndarray, xy: np.ndarray, instants: np.ndarray) -> np.ndarray:
    """[F, 2] the followed car's position at each instant; before it enters the view waits where it
    enters, after it leaves the view stays where it left."""
    return np.stack([np.interp(instants, times, xy[:, 0]), np.interp(instants, times, xy[:, 1])], axis=1)


def follow_the_action(
    ids: np.ndarray,
    xy: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    shown: np.ndarray,
    preferred: np.ndarray,
) -> tuple[np.ndarray, list[str | None]]:
    """([F, 2] view centres, the vehicle followed per frame) for frames showing FCD steps `shown`
    (rows starts[s]:ends[s] of `ids`/`xy`): the view stays on one vehicle while it is there, then takes
    the one present that stays longest, among the `preferred` rows' vehicles (the learned cars) if any
    is there. A frame with no vehicle keeps the last centre."""
    names = [str(vid) for vid in ids.tolist()]
    last_seen: dict[str, int] = {}
    for step in range(len(starts)):
        for vid in names[starts[step] : ends[step]]:
            last_seen[vid] = step
    centres = np.zeros((len(shown), 2))
    followed: list[str | None] = []
    current: str | None = None
    centre = np.nanmean(xy, axis=0)
    for k, step in enumerate(shown.tolist()):
        rows = range(starts[step], ends[step])
        here = {names[r]: r for r in rows}
        if current not in here and here:
            pool = [r for r in rows if preferred[r]] or list(rows)
            current = names[max(pool, key=lambda r: (last_seen[names[r]], -r))]
        if current in here:
            centre = xy[here[current]]
        centres[k] = centre
        followed.append(current if current in here else None)
    return centres, followed


def fit_view(
    low: np.ndarray, high: np.ndarray, x_scale: float = 1.0, ratios: tuple[float, float] = (0.3, 1.0)
) -> tuple[np.ndarray, np.ndarray, float]:
    """Limits holding [low, high], widened about its centre to a height/width ratio within `ratios`
    (a 3 km straight road still gets a strip of picture), and that ratio. `x_scale`: the length of
    an x unit in y units (cos(latitude) for lon/lat)."""
    width = max(float(high[0] - low[0]) * x_scale, 1e-9)
    height = max(float(high[1] - low[1]), 1e-9)
    ratio = float(np.clip(height / width, *ratios))
    centre = (np.asarray(low, float) + np.asarray(high, float)) / 2
    half = np.array([max(width, height / ratio) / x_scale, max(height, width * ratio)]) / 2
    return centre - half, centre + half, ratio


def named_net(fcd: Path) -> Path | None:
    """The net an XML FCD names (behave's header or SUMO's option comment), where such a file
    exists: as written, beside the FCD, or as a bundled scenario's net."""
    if fcd.suffix.lower() != ".xml":
        return None
    with open(fcd, encoding="utf-8", errors="replace") as f:
        head = f.read(65536).split("<fcd-export", 1)[0]
    found = NET_NAME.search(head) or SUMO_NET_FILE.search(head)
    if found is None:
        return None
    from sumo_scenarios import data_dir

    name = Path(found[1])
    candidates = [name, fcd.parent / name, *sorted(data_dir().glob(f"*/{name.name}"))]
    return next((path for path in candidates if path.is_file()), None)


def road_shapes(net: Path) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """(lane surfaces as polygons, lane markings between lanes, road edges) of a net's car lanes."""
    from behaviors.road.geometry_build import offset_polyline
    from sumo_scenarios.net import read_net

    try:
        tables = read_net(net)
    except (OSError, ValueError, EOFError, SyntaxError) as err:  # ET.ParseError is a SyntaxError
        raise BehaveError(f"{net} is not a SUMO net ({err})") from None
    if not tables.edges:
        raise BehaveError(f"{net} is not a SUMO net (no lanes a car may use)")
    outer = 1.0 if tables.lefthand else -1.0  # lane 0's outer side: right, or left in left-hand nets
    surfaces: list[np.ndarray] = []
    markings: list[np.ndarray] = []
    edges: list[np.ndarray] = []
    for _, lanes, normal in tables.edges:
        for k, (_, shape, width, _, _) in enumerate(lanes):
            points = distinct_points(np.asarray(shape, float).reshape(-1, 2))
            if len(points) < 2:
                continue
            inner_side = offset_polyline(points, -outer * width / 2)
            outer_side = offset_polyline(points, outer * width / 2)
            surfaces.append(np.concatenate([outer_side, inner_side[::-1]]))
            if not normal:
                continue
            (edges if k == 0 else markings).append(outer_side)
            if k == len(lanes) - 1:
                edges.append(inner_side)
    return surfaces, markings, edges


def distinct_points(points: np.ndarray) -> np.ndarray:
    """A polyline without repeated points (a zero-length segment has no direction to offset)."""
    if len(points) < 2:
        return points
    keep = np.concatenate([[True], np.hypot(*np.diff(points, axis=0).T) > 1e-6])
    return points[keep]


def vehicle_colours(df: pd.DataFrame, classes: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, str]]:
    """Each record's colour by its own vType (an agent SUMO drives for a while keeps its colour; a
    scenario car `--share` converted changes colour as it becomes an agent), SUMO's vehicles by their
    vClass (`classes`, one per record; CLASS_STYLES), and the legend."""
    import pandas as pd

    from behaviors.report.plot import GROUP_STYLES, SUMO_CAR
    from behaviors.report.realism_tracks import group_names

    groups = group_names(df["id"], df["type"], "type").to_numpy(dtype=object)
    if classes is None:
        classes = np.full(len(df), "passenger", dtype=object)
    pairs = pd.Series(list(zip(groups.tolist(), classes.tolist(), strict=True)), dtype=object)
    styles = {
        pair: GROUP_STYLES.get(pair[0]) or CLASS_STYLES.get(pair[1], SUMO_CAR) for pair in pairs.unique()
    }
    colours = pairs.map(lambda pair: styles[pair][1]).to_numpy(dtype=object)
    legend = dict(sorted({label: colour for label, colour in styles.values()}.items()))
    return colours, legend


def vehicle_kinds(df: pd.DataFrame, files: list[Path]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per record: length, width (m) and vClass of its vType, as `files` define it (vtypes.kind_of)."""
    from behaviors.sumo.vtypes import kind_of, read_vtypes

    known = read_vtypes(files)
    types = df["type"].astype(str).fillna("")
    kinds = {vtype: kind_of(vtype, known) for vtype in types.unique()}
    length = types.map(lambda v: kinds[v].length).to_numpy(float)
    width = types.map(lambda v: kinds[v].width).to_numpy(float)
    return length, width, types.map(lambda v: kinds[v].vclass).to_numpy(dtype=object)


def vtype_files(fcd: Path, sumocfg: Path | None) -> list[Path]:
    """Where the FCD's vTypes are defined: behave's own, the files its header names, and `sumocfg`'s
    route and additional files (read in this order: a later definition wins)."""
    from behaviors.sumo.scenario_config import read_sumocfg
    from behaviors.sumo.vtypes import files_named_by
    from sumo_scenarios import data_dir
    from sumo_scenarios.build import VTYPES_FILE

    files = [data_dir() / "common" / VTYPES_FILE, *files_named_by(fcd)]
    if sumocfg is not None:
        scenario = read_sumocfg(sumocfg)
        files += [*scenario.routes, *scenario.additional]
    return files


def animate_fcd(
    fcd: Path,
    out: Path,
    options: AnimateOptions,
    on_frame: Callable[[int, int], None] | None = None,
    on_status: Callable[[str], None] | None = None,
) -> int:
    """Draw the animation of `fcd` into `out` (.gif or .mp4); returns the number of frames."""
    from behaviors.report.fcd_read import read_fcd

    options.validate()
    check_animation_output(out)
    df = read_fcd(fcd, geo=options.geo)
    xcol, ycol = ("lon", "lat") if "lon" in df.columns else ("x", "y")
    df = df.dropna(subset=["time", xcol, ycol]).sort_values(["time", "id"], kind="stable")
    if df.empty:
        raise BehaveError(f"{fcd} has no vehicle records to animate")
    net = options.net if options.net is not None else named_net(fcd)
    if net is not None and not net.is_file():
        raise BehaveError(f"net file not found: {net}")
    if xcol == "lon" and net is not None:
        net = None
        _say(on_status, "the FCD holds lon/lat: lanes are drawn only for metres (x/y)")
    elif net is None:
        _say(on_status, "no net given and the FCD names none found here: lanes not drawn (give --net)")
    times = df["time"].to_numpy()
    steps, starts = np.unique(times, return_index=True)
    ends = np.append(starts[1:], len(times))
    xy = df[[xcol, ycol]].to_numpy(float)
    angle = df["angle"].fillna(90.0).to_numpy(float)
    length, width, classes = vehicle_kinds(df, vtype_files(fcd, options.sumocfg))
    colours, legend = vehicle_colours(df, classes)
    ids = df["id"].to_numpy(dtype=object)
    geo = xcol == "lon"
    shapes = road_shapes(net) if net is not None else ([], [], [])
    scale = _degree_scale(xy) if geo else (1.0, 1.0)
    view = whole_view(xy, shapes, geo)
    first, last = float(steps[0]), float(steps[-1])
    follow, auto = options.follow, False
    if follow is not None:
        mine = ids == follow
        if not mine.any():
            sample = ", ".join(sorted(set(ids.tolist()))[:5])
            raise BehaveError(f"--follow {follow}: no such vehicle in {fcd} (it has {sample}, ...)")
        first, last = float(times[mine].min()), float(times[mine].max())
        if (first, last) != (float(steps[0]), float(steps[-1])):
            _say(on_status, f"following {follow}: frames from t = {first:g} to {last:g} s, while it is in "
                 f"the FCD (which runs from {steps[0]:g} to {steps[-1]:g} s)")  # fmt: skip
    elif not options.whole:
        pixels = FIGURE_WIDTH_IN * DPI * CAR_LENGTH / view.width_m(scale)
        auto = pixels < MIN_CAR_PX
        if auto:
            _say(on_status, f"the road is {view.width_m(scale) / 1000:.1f} km across: a {CAR_LENGTH:g} m car "
                 f"would be {pixels:.1f} px long in the whole view; the view follows the learned cars "
                 f"{AUTO_WINDOW_M:g} m wide (--whole: the whole road; --follow ID: one vehicle)")  # fmt: skip
    instants = frame_times(first, last, options.every)
    shown = step_at(steps, instants)
    centres, followed, window = None, [follow] * len(instants), options.window
    if follow is not None:
        centres = follow_centres(times[ids == follow], xy[ids == follow], instants)
    elif auto:
        from behaviors.report.plot import GROUP_STYLES

        learned = np.isin(colours, [colour for _, colour in GROUP_STYLES.values()])
        centres, followed = follow_the_action(ids, xy, starts, ends, shown, learned)
        window = AUTO_WINDOW_M
    figure, axes = _figure(view, shapes, geo, 1.0 if follow is not None else view.ratio)
    _legend(axes, legend, follow, auto, wide=follow is None and view.ratio < 0.5)
    from matplotlib.collections import PolyCollection

    cars = PolyCollection([], edgecolors="black", linewidths=0.3, zorder=3)
    axes.add_collection(cars)
    stamp = axes.text(0.01, 0.98, "", transform=axes.transAxes, va="top", ha="left", zorder=5,
                      bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})  # fmt: skip
    writer = movie_writer(out, options.fps)
    with atomic_path(out) as tmp, writer.saving(figure, str(tmp), DPI):
        for k, (instant, step) in enumerate(zip(instants.tolist(), shown.tolist(), strict=True)):
            rows = slice(starts[step], ends[step])
            boxes = car_boxes(xy[rows, 0], xy[rows, 1], angle[rows], length[rows] * scale[0],
                              width[rows] * scale[1])  # fmt: skip
            cars.set_verts(list(boxes))
            cars.set_facecolor(list(colours[rows]))
            cars.set_linewidth(np.where(ids[rows] == followed[k], 1.5, 0.3).tolist())
            stamp.set_text(time_label(instant, options.every))
            if centres is not None:
                _centre_on(axes, centres[k], window, scale, 1.0 if follow is not None else view.ratio)
            writer.grab_frame()
            if on_frame:
                on_frame(k + 1, len(instants))
    return len(instants)


def movie_writer(out: Path, fps: int) -> Any:
    """Pillow's GIF writer (palette frames) or matplotlib's ffmpeg writer: both `saving(figure,
    path, dpi)` and `grab_frame()`."""
    if out.suffix.lower() == ".gif":
        return PaletteGifWriter(fps=fps)
    from matplotlib.animation import FFMpegWriter

    ffmpeg_found()  # points matplotlib at the video extra's ffmpeg where PATH has none
    return FFMpegWriter(fps=fps, codec="libx264", extra_args=["-pix_fmt", "yuv420p"])


def _say(on_status: Callable[[str], None] | None, text: str) -> None:
    if on_status:
        on_status(text)


def _degree_scale(xy: np.ndarray) -> tuple[float, float]:
    """Degrees of (lon, lat) per metre near the records, so boxes keep their size on a geo FCD."""
    lat = math.radians(float(np.nanmean(xy[:, 1])))
    metres = 111_320.0
    return 1 / (metres * max(math.cos(lat), 1e-6)), 1 / metres


@dataclass(frozen=True)
class View:
    """The whole area: the net's and the records' (`fit_view`'s limits and height/width ratio)."""

    low: np.ndarray
    high: np.ndarray
    ratio: float
    x_scale: float  # the length of an x unit in y units (cos(latitude) for lon/lat)

    def width_m(self, scale: tuple[float, float]) -> float:
        """The width in metres (`scale`: the coordinates' units per metre, as _degree_scale)."""
        return float(self.high[0] - self.low[0]) / scale[0]


def whole_view(
    xy: np.ndarray, shapes: tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]], geo: bool
) -> View:
    surfaces = shapes[0]
    points = np.concatenate([xy, *surfaces]) if surfaces else xy
    low, high = np.nanmin(points, axis=0), np.nanmax(points, axis=0)
    margin = 0.0 if geo else MARGIN_M
    x_scale = math.cos(math.radians(float(np.nanmean(xy[:, 1])))) if geo else 1.0
    low, high, ratio = fit_view(low - margin, high + margin, x_scale)
    return View(low, high, ratio, x_scale)


def _figure(
    view: View,
    shapes: tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]],
    geo: bool,
    ratio: float,
) -> tuple[Figure, Axes]:
    """The figure with the road drawn once, `ratio` high for its width (the whole view's, or a
    followed window's)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection, PolyCollection
    from matplotlib.figure import Figure

    surfaces, markings, edges = shapes
    low, high, x_scale = view.low, view.high, view.x_scale
    size = (FIGURE_WIDTH_IN, round(FIGURE_WIDTH_IN * ratio, 2))
    figure = Figure(figsize=size, dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.add_subplot()
    axes.add_collection(PolyCollection(surfaces, facecolors=ROAD_COLOUR, edgecolors="none", zorder=1))
    dashed = {"linewidths": 0.6, "linestyles": (0, (4, 4))}
    axes.add_collection(LineCollection(markings, colors=MARKING_COLOUR, zorder=2, **dashed))
    axes.add_collection(LineCollection(edges, colors=MARKING_COLOUR, linewidths=1.0, zorder=2))
    axes.set_xlim(low[0], high[0])
    axes.set_ylim(low[1], high[1])
    axes.set_aspect(1.0 / max(x_scale, 1e-6), adjustable="box")  # the limits already fit the figure
    axes.set_xlabel("lon [deg]" if geo else "x [m]")
    axes.set_ylabel("lat [deg]" if geo else "y [m]")
    axes.set_facecolor("white")
    return figure, axes


def _legend(
    axes: Axes, legend: dict[str, str], follow: str | None, auto: bool = False, wide: bool = False
) -> None:
    """The legend; `wide` (a strip of a figure): in one row, so as not to hide the road."""
    from matplotlib.patches import Patch

    handles = [Patch(facecolor=colour, edgecolor="black", label=label) for label, colour in legend.items()]
    if follow is not None or auto:
        label = f"followed: {follow}" if follow is not None else "followed (the view follows it)"
        handles.append(Patch(facecolor="none", edgecolor="black", linewidth=1.5, label=label))
    where: Literal["lower center", "upper right"] = "lower center" if wide else "upper right"
    axes.legend(
        handles=handles, loc=where, fontsize="small", framealpha=0.9, ncols=len(handles) if wide else 1
    )


def _centre_on(
    axes: Axes, centre: np.ndarray, window: float, scale: tuple[float, float], ratio: float = 1.0
) -> None:
    """The view `window` metres wide and `ratio` as high about `centre`."""
    half_x, half_y = window / 2 * scale[0], window * ratio / 2 * scale[1]
    axes.set_xlim(centre[0] - half_x, centre[0] + half_x)
    axes.set_ylim(centre[1] - half_y, centre[1] + half_y)


class PaletteGifWriter:
    """matplotlib's movie-writer protocol (`saving`, `grab_frame`) for GIF through Pillow, keeping
    each frame as an 8-bit palette image, a quarter of PillowWriter's RGBA frame (docs/history.md)."""

    COLOURS = 64

    def __init__(self, fps: int) -> None:
        self.fps = fps
        self.frames: list[Any] = []
        self.figure: Figure | None = None

    def saving(self, figure: Figure, path: str, dpi: float) -> _Saving:
        return _Saving(self, figure, path)

    def grab_frame(self) -> None:
        from PIL import Image

        assert self.figure is not None
        canvas = self.figure.canvas
        canvas.draw()
        rgba = np.asarray(canvas.buffer_rgba())  # type: ignore[attr-defined]
        image = Image.fromarray(rgba[..., :3].copy())
        self.frames.append(image.quantize(colors=self.COLOURS, method=Image.Quantize.MEDIANCUT))

    def finish(self, path: str) -> None:
        if not self.frames:
            return
        first, *rest = self.frames
        duration = round(1000 / self.fps)
        first.save(path, format="GIF", save_all=True, append_images=rest, duration=duration, loop=0)


class _Saving:
    """`with writer.saving(figure, path, dpi):` frames are grabbed inside, the file written at exit."""

    def __init__(self, writer: PaletteGifWriter, figure: Figure, path: str) -> None:
        self.writer, self.figure, self.path = writer, figure, path

    def __enter__(self) -> PaletteGifWriter:
        self.writer.figure = self.figure
        self.writer.frames = []
        return self.writer

    def __exit__(self, kind: object, *rest: object) -> None:
        if kind is None:
            self.writer.finish(self.path)
        self.writer.frames = []
