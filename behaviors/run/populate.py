"""`behave populate`: learned keepers and overtakers on any SUMO network with multi-lane edges.

Design choices (see README, "Populate"):
* Agents only get routes made of multi-lane edges (following the network's
  connections between them): the learned behaviour was trained on multi-lane
  carriageways, so single-lane ramps and side roads are never entered; the
  junctions between two multi-lane edges are driven by the policy (their lane
  axes are known, their borders are the neighbouring edges').
* SUMO picks free insertion places (`departPos="random_free"`), so nobody is
  inserted on top of another car; an agent that could not be inserted is
  withdrawn and tried again elsewhere on the next step.
* A safety shield (shield.py, on by default) cuts sideways moves towards a car
  alongside and speeds that could not stop behind the car ahead: the policies
  learnt among a few cars and, in dense traffic, drift into their neighbours and
  run into slower cars. `shield=False` drives with the bare policy.
* The whole fleet acts through one batched policy call per step.
* `--sumocfg` runs a user's scenario as its sumocfg sets it (scenario_config.py), and
  `share` turns that fraction of its passenger cars into agents when they depart: which
  cars is fixed by the seed and the car's id (a hash), not by what happens in the run, and
  the others stay SUMO's, driving as in the plain SUMO run until they meet an agent.
* SUMO writes the FCD itself (so the format is exactly SUMO's), to a temporary
  file that is renamed into place only when the run completed. Ctrl-C ends the run
  after the step under way: what was simulated is kept as a whole FCD (and agents
  table), and `populate` raises PopulateInterrupted with the summary marked cut short.
* `gui` runs the same simulation in sumo-gui (libsumo's own GUI), coloured by vType.
* `connect` joins a SUMO another program runs, as one more TraCI client (joined.py, `populate_joined`):
  the same share rules and driver, no FCD of its own (SUMO's outputs hold every vehicle), the
  agents still on the road handed back to SUMO when behave leaves (docs/manual/connect.md).
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from behaviors.errors import BehaveError
from behaviors.files import check_output_path
from behaviors.learn.policy import RULES, Policy
from behaviors.report.agents_table import agents_path
from behaviors.report.export import require_projection
from behaviors.run.fcd_sealing import finish_fcd, partial_path
from behaviors.run.populate_config import PopulateConfig, checkpoint_step, trained_step
from behaviors.run.population import Population
from behaviors.run.precision import POLICY_THREADS
from behaviors.run.records import PopulateSummary, write_agents_csv
from behaviors.sumo.fcd_parquet import ParquetStream
from behaviors.sumo.interrupt import sigint_between_steps
from behaviors.sumo.joined import SUMO_NET, JoinedSim
from behaviors.sumo.scenario_config import LATERAL_RESOLUTION
from behaviors.sumo.sim import SumoStopped, sumo_stopped
from behaviors.sumo.traci_connection import connection_closed, parse_address


def populate(
    config: PopulateConfig,
    on_step: Callable[[float], None] | None = None,
    on_status: Callable[[str], None] | None = None,
    policy: Policy | None = None,
) -> PopulateSummary:
    """Run the whole simulation; the FCD file and the per-agent table beside it appear only if the
    run completed. `policy`: one already loaded drives instead of config.policy (the Python API's
    way to hold a policy's actions constant, policy.held_constant, or to record them)."""
    if config.connect is not None:
        return populate_joined(config, on_step, on_status, policy)
    config.validate()
    check_output_path(config.fcd)
    check_output_path(agents_path(config.fcd))
    if config.geo:
        require_projection(config.net, "--geo writes lon/lat: the net needs a geo projection")
    torch.set_num_threads(POLICY_THREADS)
    population = Population(config, on_status, policy)
    partial = partial_path(config.fcd)
    stream: ParquetStream | None = None
    stopped: SumoStopped | None = None
    start = time.perf_counter()
    try:
        if on_status:
            on_status("starting SUMO")
        if config.fcd.suffix == ".parquet":  # SUMO's own parquet writer keeps the whole trace in memory
            stream = ParquetStream(partial, geo=config.geo, final=config.fcd)
        population.start(partial if stream is None else stream.source, precise=stream is not None)
        steps = round(config.duration / config.step_length)
        with sigint_between_steps() as interrupted:
            for _ in range(steps):
                try:
                    population.step()
                except Exception as exc:  # SUMO failing mid-run: keep what it simulated
                    stopped = sumo_stopped(exc, population.sim.options) if population.sim else None
                    if stopped is None:
                        raise
                    population.summary.cut_short = True
                    break
                if on_step:
                    on_step(population.summary.simulated_s)
                if interrupted():
                    population.summary.cut_short = True
                    break
        driving = population.log.driving(population.now)
        population.close()  # SUMO closes its outputs
        last_time = finish_fcd(partial, config.fcd, config, population.now - config.step_length,
                               population.summary.cut_short, stream, stopped is not None)  # fmt: skip
        write_agents_csv(agents_path(config.fcd), population.log.ended, driving)
        population.summary.count_agents(population.log.ended, driving)
        if population.summary.sumo is not None:
            population.summary.sumo.finish()
    except BehaveError as err:
        if stopped is None or err is stopped:
            raise
        raise BehaveError(f"{stopped}; {err}") from None  # nothing kept: the first error, then why
    finally:
        population.close()
        if stream is not None:
            stream.close()
        population.log.ended.close()
        with contextlib.suppress(FileNotFoundError):
            partial.unlink()
    population.summary.wall_s = time.perf_counter() - start
    population.summary.phases = dict(population.timer.seconds)
    if stopped is not None:
        raise PopulateStopped(
            f"{stopped}; {config.fcd} and its agents table hold the run up to t={last_time:g} s (cut short)",
            population.summary,
        )
    if population.summary.cut_short:
        raise PopulateInterrupted(population.summary)
    return population.summary


class PopulateStopped(BehaveError):
    """SUMO failed during `populate` (sim.SumoStopped); the FCD and agents table up to its last whole
    step were written, marked cut short as a Ctrl-C's are, and `.summary` is the run's. The message is
    SUMO's error and what was kept, one line."""

    def __init__(self, message: str, summary: PopulateSummary) -> None:
        super().__init__(message)
        self.summary = summary


class PopulateInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped `populate` between two steps; the FCD and agents table up to the last whole
    step were written (complete files, sealed as a finished run's). Still a KeyboardInterrupt, so a
    caller that does not look for it stops as on any Ctrl-C."""

    def __init__(self, summary: PopulateSummary) -> None:
        super().__init__(f"interrupted after {summary.simulated_s:g} simulated seconds")
        self.summary = summary


def joined_agents_path(config: PopulateConfig) -> Path:
    return config.agents_csv if config.agents_csv is not None else agents_path(config.fcd)


def populate_joined(
    config: PopulateConfig,
    on_step: Callable[[float], None] | None = None,
    on_status: Callable[[str], None] | None = None,
    policy: Policy | None = None,
) -> PopulateSummary:
    """`populate` inside a simulation another program runs (config.connect, docs/manual/connect.md):
    join it as TraCI client number config.order, turn config.share of its passenger cars into agents
    as `--sumocfg --share` does, step in lockstep with the other clients until the simulation is over,
    SUMO closes the connection, config.duration or Ctrl-C; then give the agents still on the road back
    to SUMO's driver and close this client only (SUMO runs on with the others). Writes the agents
    table (`joined_agents_path`), no FCD: SUMO's own outputs hold every vehicle."""
    config.validate()
    table = joined_agents_path(config)
    check_output_path(table)
    torch.set_num_threads(POLICY_THREADS)
    address = parse_address(config.connect or "")
    if on_status:
        on_status(f"joining SUMO at {address} as client {config.order}")
    sim = JoinedSim(address, config.order, None if config.net == SUMO_NET else config.net)
    population: Population | None = None
    start = time.perf_counter()
    end = "simulation_over"
    try:
        config = joinable(sim, config, policy)
        population = Population(config, on_status, policy, joined=sim)
        sim.check_net(set(population.geometry.edges))
        population.start(None)
        summary = population.summary
        with sigint_between_steps() as interrupted:
            while not sim.over:
                if summary.simulated_s >= config.duration - 1e-9:
                    end = "duration"
                    break
                try:
                    population.step()
                except Exception as exc:
                    if not connection_closed(exc):
                        raise
                    sim.gone = sim.gone or str(exc) or type(exc).__name__
                    end = "closed_by_sumo"
                    break
                if on_step:
                    on_step(summary.simulated_s)
                if interrupted():
                    end = "interrupted"
                    break
        driving = population.driving_rows()
        population.close()  # the agents still driving go back to SUMO, this client leaves
        write_agents_csv(table, population.log.ended, driving)
        summary.count_agents(population.log.ended, driving)
        if summary.sumo is not None:
            summary.sumo.finish()
        summary.left_simulation, summary.handed_back = end, sim.handed_back
        summary.left_note = joined_note(end, address, sim, summary)
    finally:
        if population is not None:
            population.close()
            population.log.ended.close()
        sim.close()
    summary.wall_s = time.perf_counter() - start
    assert population is not None
    summary.phases = dict(population.timer.seconds)
    if end == "interrupted":
        summary.cut_short = True
        raise PopulateInterrupted(summary)
    return summary


def joinable(sim: JoinedSim, config: PopulateConfig, policy: Policy | None) -> PopulateConfig:
    """The config with the joined simulation's net and step, or BehaveError if the agents cannot drive
    in it: a step their policy was not trained at, or no sublanes to move sideways in."""
    given = {"policy": config.policy, "driver": config.driver}
    trained = checkpoint_step(policy.path) if policy is not None else trained_step(given)
    name = (
        policy.label if policy is not None else RULES if config.driver == RULES else Path(config.policy).stem
    )
    if not math.isclose(sim.step_length, trained):
        raise BehaveError(
            f"SUMO at {sim.address} steps {sim.step_length:g} s; {name} was trained at {trained:g} s steps "
            f"and drives at no other: start SUMO with --step-length {trained:g}"
        )
    if sim.lateral_resolution <= 0:
        raise BehaveError(
            f"SUMO at {sim.address} runs without sublanes, and the agents move sideways within their lanes: "
            f"start SUMO with --lateral-resolution {LATERAL_RESOLUTION:g}"
        )
    return replace(config, net=sim.net, step_length=sim.step_length)


def joined_note(end: str, address: Any, sim: JoinedSim, summary: PopulateSummary) -> str:
    """What happened at the end of a joined run, one line."""
    at = f"at t={sim.time:g} s"
    back = (
        f"{sim.handed_back} agents handed back to SUMO's driver, SUMO runs on with the other clients"
        if sim.handed_back
        else "SUMO runs on with the other clients"
    )
    return {
        "simulation_over": f"the simulation at {address} ended {at} (no vehicles left to run): left it",
        "closed_by_sumo": f"SUMO at {address} closed the connection {at} ({sim.gone}): ended or stopped",
        "duration": f"left SUMO at {address} after {summary.simulated_s:g} simulated s {at}; {back}",
        "interrupted": f"interrupted (Ctrl-C) {at}: left SUMO at {address}; {back}",
    }[end]
