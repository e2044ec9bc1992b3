"""behave among the tools researchers use: a quick CLI, an installable package, PettingZoo,
SuperSuit + Stable-Baselines3, Gymnasium and TensorBoard."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from behaviors.errors import BehaveError
from behaviors.learn.env import BehaveEnv, make_env
from behaviors.report.render import AGENT, ROAD

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("torch", "pandas", "matplotlib", "libsumo", "sumolib", "traci")


@pytest.mark.parametrize("command", [[], ["train"], ["populate"], ["evaluate"], ["report"], ["plot"],
                                     ["export"], ["scenario"], ["scenario", "list"]])  # fmt: skip
def test_help_imports_no_heavy_library(command: list[str]) -> None:
    """`behave [CMD] --help` must answer at once: building the app and showing help loads none of
    torch, pandas, matplotlib or SUMO's libraries (a module check, not a timing)."""
    probe = (
        "import sys\n"
        "from behaviors.cli.main import main\n"
        f"sys.argv = ['behave', *{command!r}, '--help']\n"
        "try:\n    main()\n"
        "except SystemExit as exit:\n    assert exit.code in (0, None), exit.code\n"
        f"print('loaded:', *(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert "Usage: behave" in result.stdout
    assert result.stdout.splitlines()[-1] == "loaded:"


def test_cli_defaults_are_the_configs() -> None:
    """The CLI spells its defaults out (so --help needs no torch or pandas): they must stay the
    library's."""
    from behaviors.cli import populate, report, train
    from behaviors.learn.train_config import TrainConfig
    from behaviors.report import realism_tracks
    from behaviors.run.populate_config import DEFAULT_POLICY, PopulateConfig

    assert vars(train.DEFAULTS) == TrainConfig().options()  # every setting of a run, by option name
    defaults = vars(populate.DEFAULTS)
    assert defaults == {name: getattr(PopulateConfig(), name) for name in defaults}
    assert populate.DEFAULT_POLICY == DEFAULT_POLICY
    assert (report.GROUP_BY, report.SKIP_S) == (realism_tracks.GROUP_BY, realism_tracks.SKIP_S)


def test_behave_train_takes_every_setting_of_a_run() -> None:
    """Its options are TrainConfig's (train_config.OPTIONS), no more and no fewer: none can drift apart."""
    import inspect

    from behaviors.cli import train
    from behaviors.learn.train_config import OPTIONS

    command_only = {"out", "resume", "ray_address", "quiet", "verbose"}  # how it reports, not what it trains
    assert set(inspect.signature(train.train).parameters) - command_only == set(OPTIONS)


def test_wheel_installs_the_cli_under_behaviors(tmp_path: Path) -> None:
    """The built wheel holds behaviors/cli/ and no top-level `cli`, and `behave` points into it."""
    source = tmp_path / "src"
    for part in ("behaviors", "cli", "sumo_scenarios"):
        shutil.copytree(ROOT / part, source / part, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    command = [sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "--no-build-isolation", "-q"]
    subprocess.run([*command, "-w", str(tmp_path)], capture_output=True, check=True, cwd=tmp_path)
    (wheel,) = tmp_path.glob("behave_traffic-*.whl")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        entry_points = next(n for n in names if n.endswith("entry_points.txt"))
        scripts = archive.read(entry_points).decode()
    top_level = {name.split("/")[0] for name in names if "dist-info" not in name}
    assert top_level == {"behaviors", "sumo_scenarios"}
    assert "behaviors/cli/main.py" in names
    assert "behave = behaviors.cli.main:main" in scripts


def log_steps(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, int]]:
    """(agents before, agents after) of every BehaveEnv step, also in the copies wrappers make."""
    rows: list[tuple[int, int]] = []
    step = BehaveEnv.step

    def logged(env: BehaveEnv, actions: dict):
        before = len(env.agents)
        result = step(env, actions)
        rows.append((before, len(env.agents)))
        return result

    monkeypatch.setattr(BehaveEnv, "step", logged)
    return rows


@pytest.mark.sumo
def test_stepping_after_the_last_agent_left_returns_empty_dicts() -> None:
    """SuperSuit and RLlib step once more after every agent is done: five empty dicts, no error."""
    env = make_env("tiny", agents=1, max_steps=3, seed=0)
    try:
        env.reset(seed=0)
        while env.agents:
            env.step({a: np.zeros(3, np.float32) for a in env.agents})
        assert env.step({}) == ({}, {}, {}, {}, {})
    finally:
        env.close()


@pytest.mark.sumo
def test_rgb_array_draws_the_road_and_the_agents() -> None:
    env = make_env("tiny", agents=2, max_steps=5, seed=0, render_mode="rgb_array")
    try:
        assert env.render_mode == "rgb_array" and "rgb_array" in env.metadata["render_modes"]
        env.reset(seed=0)
        image = env.render()
        assert image.shape == (256, 256, 3) and image.dtype == np.uint8
        assert (image == ROAD).all(-1).sum() > 100  # the lane axes
        assert (image == AGENT).all(-1).sum() >= 9  # at least one 3x3 agent square
    finally:
        env.close()
    with pytest.raises(BehaveError, match="render_mode"):
        make_env("tiny", agents=1, render_mode="human")


@pytest.mark.sumo
@pytest.mark.train
def test_supersuit_black_death_and_sb3_td3_learn_through_agents_leaving_at_different_times(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """SuperSuit's vector env (black death for agents that left) feeds SB3's TD3 for a few hundred
    steps; the episodes end with agents leaving one by one (so fewer act than were started)."""
    ss = pytest.importorskip("supersuit")
    sb3 = pytest.importorskip("stable_baselines3")
    env = make_env("tiny", agents=2, max_steps=80, seed=0)
    rows = log_steps(monkeypatch)
    venv = ss.pettingzoo_env_to_vec_env_v1(ss.black_death_v3(env))
    venv = ss.concat_vec_envs_v1(venv, 1, num_cpus=0, base_class="stable_baselines3")
    try:
        model = sb3.TD3("MlpPolicy", venv, learning_starts=100, train_freq=8, gradient_steps=2,
                        policy_kwargs={"net_arch": [32, 32]})  # fmt: skip
        model.learn(total_timesteps=300)
    finally:
        venv.close()
    assert any(before == 1 for before, _ in rows)  # one agent drove on after the other left
    assert sum(1 for before, left in rows if before and not left) >= 2  # several episodes ended
    assert model.num_timesteps >= 300


@pytest.mark.sumo
def test_sb3_parallel_vec_env_seed_sets_the_next_episode() -> None:
    """`seed(s)` reaches the PettingZoo env's next reset: the same seed, the same first
    observations; another seed, others (the env was made with seed 0 for all three)."""
    pytest.importorskip("supersuit")
    from behaviors.learn.sb3 import sb3_parallel_vec_env

    venv = sb3_parallel_vec_env(make_env("tiny", agents=2, max_steps=80, seed=0))
    try:
        firsts = []
        for seed in (1, 1, 2):
            venv.seed(seed)
            firsts.append(venv.reset())
    finally:
        venv.close()
    assert firsts[0].shape == (2, venv.observation_space.shape[0])
    assert np.array_equal(firsts[0], firsts[1])
    assert not np.array_equal(firsts[0], firsts[2])


@pytest.mark.sumo
@pytest.mark.train
def test_td3_seed_0_on_sb3_parallel_vec_env_learns_the_same_twice() -> None:
    """`TD3(..., seed=0)` on SuperSuit's vector env crashed ("'ConcatVecEnv' object has no attribute
    'seed'"); on sb3_parallel_vec_env it runs, two runs learn the same weights and seed 1 others."""
    pytest.importorskip("supersuit")
    sb3 = pytest.importorskip("stable_baselines3")
    from behaviors.learn.sb3 import sb3_parallel_vec_env

    def learned_checksum(seed: int) -> float:
        venv = sb3_parallel_vec_env(make_env("tiny", agents=2, max_steps=80, seed=0))
        try:
            model = sb3.TD3("MlpPolicy", venv, learning_starts=100, train_freq=8, gradient_steps=2,
                            policy_kwargs={"net_arch": [32, 32]}, seed=seed, device="cpu")  # fmt: skip
            model.learn(total_timesteps=200)
        finally:
            venv.close()
        return sum(float(p.detach().double().sum()) for p in model.policy.parameters())

    assert learned_checksum(0) == learned_checksum(0) != learned_checksum(1)
