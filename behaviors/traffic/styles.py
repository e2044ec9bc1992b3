"""Driver styles: what makes one driver unlike another, drawn per agent and fed to the one shared
network (the paper's behaviour id, generalised).

Real drivers are a population: desired speeds, following headways and the eagerness to pass
differ far more between people than within one person's trip (highD: about a third of cars come
closer than 1 s to their leader at some point, the median closest headway is about 1.4 s; the
calibration literature starts from normal speed factors with a spread of 0.1-0.15 and lognormal
headways with a median near 1.4 s). Keepers and overtakers are two presets of these draws, so
existing command lines keep their meaning; a population file gives other distributions.
"""

from __future__ import annotations

import json
from dataclasses import MISSING, dataclass, fields, replace
from pathlib import Path

import numpy as np

from behaviors.errors import BehaveError

DESIRED_SPEED = {0.0: (0.85, 1.0), 1.0: (1.02, 1.12)}
"""Desired speed as a fraction of the limit, drawn per agent: keepers (0) and overtakers (1). Drivers
want about the limit, as SUMO's cars do (speed factor 1 +- 0.1), since the slowest set the pace of
whole lanes; overtakers are the faster drivers, up to SUMO's top sixth, so that they pass most of
SUMO's cars (docs/history.md, "Why some rules of the code exist")."""

LANE_BIAS_SD = 0.3
"""m: drivers hold themselves off their lane's centre line, each in its own place (highD: a mean of
about 0.3 m off it; a normal of this spread has a mean |offset| of 0.24 m)."""
LANE_BIAS_MAX = 0.5
"""m: never further off than this (a 1.8 m car in a 3.5 m lane has 0.85 m of room each side)."""
HEADWAY_RANGE = (0.5, 3.0)
"""s: the time headways a style may ask for, and that the network's accel action spans."""


@dataclass(frozen=True)
class StyleDistribution:
    """How one kind of driver's style is drawn: speed factor ~ normal, clipped; time headway ~
    lognormal (median, sigma of its log), clipped to HEADWAY_RANGE; eagerness to pass ~ Beta."""

    speed_mean: float
    speed_sd: float
    speed_range: tuple[float, float]
    headway_median: float
    headway_sigma: float
    eagerness_a: float
    eagerness_b: float
    top_speed_range: tuple[float, float] = (np.inf, np.inf)  # m/s: a speed limiter's setting (lorries)
    lane_bias_sd: float = LANE_BIAS_SD

    def check(self, name: str) -> None:
        low, high = self.speed_range
        ok = (
            0.3 <= low <= self.speed_mean <= high <= 1.6
            and self.speed_sd >= 0
            and HEADWAY_RANGE[0] <= self.headway_median <= HEADWAY_RANGE[1]
            and 0 <= self.headway_sigma <= 1.0
            and self.eagerness_a > 0
            and self.eagerness_b > 0
            and 5.0 <= self.top_speed_range[0] <= self.top_speed_range[1]
            and 0 <= self.lane_bias_sd <= LANE_BIAS_MAX
        )
        if not ok:
            raise BehaveError(f"population '{name}': a style distribution is out of range: {self}")


KEEPER = StyleDistribution(0.93, 0.06, (0.8, 1.05), 1.6, 0.3, 2.0, 6.0)
"""Lane keepers: at or under the limit, longer headways, seldom pass (eagerness mean 0.25)."""
OVERTAKER = StyleDistribution(1.07, 0.06, (0.95, 1.25), 1.25, 0.3, 6.0, 2.0)
"""Overtakers: faster, closer, keen to pass (eagerness mean 0.75)."""
LORRY = StyleDistribution(1.0, 0.0, (1.0, 1.0), 2.0, 0.25, 1.0, 12.0, (80 / 3.6, 90 / 3.6), 0.15)
"""Lorries: the limit up to their limiter's 80-90 km/h, long headways (German law asks 50 m of them,
2.1 s at 85 km/h), hardly ever keen to pass (eagerness mean 0.08), near their lane's centre."""
Population = tuple[StyleDistribution, StyleDistribution, StyleDistribution]
"""The keeper, the overtaker and the lorry distribution of a population."""
KINDS = ("keeper", "overtaker", "lorry")
"""The kinds of learned vehicle, by behaviour id (0, 1, 2): the order of a population's distributions."""
HIGHD_LORRY = replace(LORRY, headway_median=1.5, headway_sigma=0.45)
"""highD's lorries follow closer than the law's 50 m: a median closest headway of 2.2 s, a sixth of
them within 1 s at some point; a lognormal of median 1.5 s and sigma 0.45 puts 18% of headways
under 1 s (a first guess from those figures, measured in docs/people.md, not fitted)."""
HIGHD = (
    StyleDistribution(0.93, 0.09, (0.75, 1.1), 1.0, 0.5, 2.0, 6.0),
    StyleDistribution(1.07, 0.09, (0.9, 1.3), 0.8, 0.5, 6.0, 2.0),
    HIGHD_LORRY,
)
"""Fitted so that every car styled on a highD-like road (`make people`: 2 lanes, 130 km/h, a fifth
lorries) comes nearest highD's published per-car figures among the populations tried
(docs/people-calibration.md): shorter and wider headways than the default, wider speeds; its lorries
are HIGHD_LORRY."""
PRESETS: dict[str, Population] = {"default": (KEEPER, OVERTAKER, LORRY), "highd": HIGHD}
"""Named populations: the keeper, the overtaker and the lorry distribution."""


@dataclass(frozen=True)
class Styles:
    """One style per agent (rows as the fleet's)."""

    desired_fraction: np.ndarray  # [N] desired speed as a share of the local limit
    time_headway: np.ndarray  # [N] s: the headway the driver wants to follow at
    eagerness: np.ndarray  # [N] in [0, 1]: how readily it passes a slower car
    lane_bias: np.ndarray  # [N] m from the lane's centre line (+ fast side) where it holds itself
    top_speed: np.ndarray  # [N] m/s it never wants to go faster than (inf: the limit's share alone)

    def __len__(self) -> int:
        return len(self.desired_fraction)


def draw_styles(
    behaviour_id: np.ndarray,
    rng: np.random.Generator,
    population: tuple[StyleDistribution, ...] = (KEEPER, OVERTAKER, LORRY),
) -> Styles:
    """A style for each agent from its kind's distribution (behaviour id: an index into KINDS)."""
    n = len(behaviour_id)
    speed, headway, eager, top, bias_sd = (np.empty(n) for _ in range(5))
    for flag, dist in enumerate(population):
        mask = behaviour_id == flag
        k = int(mask.sum())
        speed[mask] = np.clip(rng.normal(dist.speed_mean, dist.speed_sd, k), *dist.speed_range)
        headway[mask] = np.clip(
            dist.headway_median * np.exp(rng.normal(0.0, dist.headway_sigma, k)), *HEADWAY_RANGE
        )
        eager[mask] = rng.beta(dist.eagerness_a, dist.eagerness_b, k)
        low, high = dist.top_speed_range
        top[mask] = rng.uniform(low, high, k) if np.isfinite(high) else np.inf
        bias_sd[mask] = dist.lane_bias_sd
    bias = np.clip(rng.normal(0.0, 1.0, n) * bias_sd, -LANE_BIAS_MAX, LANE_BIAS_MAX)
    return Styles(speed, headway, eager, bias, top)


def fixed_styles(desired_fraction: np.ndarray) -> Styles:
    """Styles that differ only in desired speed: the middle of HEADWAY_RANGE's usual drivers (1.4 s)
    and of eagerness (0.5), for drivers whose behaviour is set otherwise."""
    n = len(desired_fraction)
    return Styles(
        np.asarray(desired_fraction, float), np.full(n, 1.4), np.full(n, 0.5), np.zeros(n), np.full(n, np.inf)
    )


def unstyled(desired_fraction: np.ndarray) -> Styles:
    """The style of drivers whose headway, eagerness and place in the lane are not drawn (their law
    and habits set them): the desired speed alone, the rest NaN."""
    nan = np.full(len(desired_fraction), np.nan)
    return Styles(np.asarray(desired_fraction, float), nan, nan.copy(), nan.copy(), np.full(len(nan), np.inf))


def read_population(name_or_path: str) -> Population:
    """A preset's name, or a JSON file {"keeper": {...}, "overtaker": {...}, "lorry": {...}} whose
    objects hold every field of StyleDistribution (top_speed_range and lane_bias_sd may be left out;
    so may "lorry", which then is the LORRY distribution)."""
    if name_or_path in PRESETS:
        return PRESETS[name_or_path]
    path = Path(name_or_path)
    if not path.is_file():
        raise BehaveError(f"population '{name_or_path}': no such preset ({', '.join(PRESETS)}) or file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        names = {f.name for f in fields(StyleDistribution)}
        needed = {f.name for f in fields(StyleDistribution) if f.default is MISSING}
        out = []
        for kind in KINDS:
            if kind == "lorry" and kind not in data:
                out.append(LORRY)
                continue
            given = data[kind]
            if not needed <= set(given) <= names:
                raise BehaveError(
                    f"population {path}: '{kind}' needs the fields {', '.join(sorted(needed))} "
                    f"(and may have {', '.join(sorted(names - needed))})"
                )
            ranges = {k: tuple(given[k]) for k in ("speed_range", "top_speed_range") if k in given}
            out.append(StyleDistribution(**{**given, **ranges}))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise BehaveError(f"population {path}: cannot read it ({exc})") from None
    for kind, dist in zip(KINDS, out, strict=True):
        dist.check(f"{path}:{kind}")
    return out[0], out[1], out[2]


def headway_of_action(accel: np.ndarray) -> np.ndarray:
    """[N] s: the time headway the network's accel action in [0, 1] asks for (1: the closest)."""
    low, high = HEADWAY_RANGE
    return high - (high - low) * np.clip(accel, 0.0, 1.0)


def action_of_headway(headway: np.ndarray) -> np.ndarray:
    """The accel action that asks for `headway` (the inverse of `headway_of_action`)."""
    low, high = HEADWAY_RANGE
    return (high - np.clip(headway, low, high)) / (high - low)


def desired_fractions(behaviour_id: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Desired speed per agent as a share of the local limit: overtakers want more than keepers."""
    out = np.empty(len(behaviour_id))
    for flag, (low, high) in DESIRED_SPEED.items():
        mask = behaviour_id == flag
        out[mask] = rng.uniform(low, high, mask.sum())
    return out
