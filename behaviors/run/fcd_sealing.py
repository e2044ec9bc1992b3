"""Where SUMO writes populate's FCD while it runs, and how the finished FCD is checked, headed and moved
into place (also when SUMO failed or Ctrl-C cut the run short)."""

from __future__ import annotations

from pathlib import Path

from behaviors.errors import BehaveError
from behaviors.files import temp_path
from behaviors.report.fcd_whole import last_whole_step, seal_fcd
from behaviors.run.populate_config import PopulateConfig
from behaviors.sumo.fcd_parquet import ParquetStream


def partial_path(final: Path) -> Path:
    """Where SUMO writes while running: a temp file beside the target with its suffix (SUMO picks
    the format by it), named so that a later run removes it if this one is killed."""
    return temp_path(final)


def finish_fcd(
    partial: Path,
    final: Path,
    config: PopulateConfig,
    last_time: float,
    cut_short: bool = False,
    stream: ParquetStream | None = None,
    stopped: bool = False,
) -> float:
    """Check SUMO's FCD is whole and move it into place; XML gets a deterministic header (equal
    seeds give equal bytes) that says whether it holds lon/lat, and where Ctrl-C cut the run short; a
    parquet `stream` the same settings as its file metadata (fcd_parquet.METADATA_KEY). `stopped`: SUMO
    failed, and the FCD ends at its own last whole step, whichever (SUMO may have written the step it
    failed in); returns the last step's time."""
    if stopped:
        if stream is not None:
            stream.wait()
        found = stream.last_time if stream is not None else last_whole_step(partial)
        if found is None:
            raise BehaveError(f"it stopped before a whole step: {final} not written")
        last_time = found
    cut = f" cut-short-after={last_time + config.step_length:g}" if cut_short else ""
    settings = (
        f"behave populate: net={config.net.name} overtakers={config.overtakers} "
        f"keepers={config.keepers} background={config.background} duration={config.duration} "
        f"step-length={config.step_length} seed={config.seed}{' geo=true' if config.geo else ''}"
        f"{f' driver={config.driver}' if config.driver else ''}"
        f"{f' sumocfg={config.sumocfg.name} share={config.share}' if config.sumocfg else ''}{cut}"
    )
    if stream is not None:
        stream.finish(settings)
    header = f"<!-- {settings} -->\n"
    seal_fcd(partial, final, header=header, geo=config.geo, last_time=last_time, step=config.step_length)
    return last_time
