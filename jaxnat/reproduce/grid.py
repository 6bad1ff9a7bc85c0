"""The experiment grid of `jaxnat reproduce`: one `Cell` per training run, by profile, and the
`Plan` of one command (the cells it runs, their seeds, the folder they go to).

The cells follow the experiments section of Zhang, Wu and Pineau (2018):

- **classify**: MNIST, CIFAR-10, CIFAR-100 x PPO / A2C / ACKTR x the paper's 3-layer CNN and
  ResNet-18 (its two classification figures), and the difficulty sweep on CIFAR-10 with PPO:
  window `w` in {2, 5, 7} at `M=20`, and steps per episode `M` in {10, 20, 40} at `w=5`.
- **localize**: Cityscapes (when present) and `Localize/Clutter-v0` (always) x the three
  algorithms x the two trunks.
- **atari**: the authors' 16 games x background none / noise / video x PPO, A2C, ACKTR and DQN
  (the four the paper evaluated there), test play on the held-out videos.
- **mujoco**: the four PixelMuJoCo robots x checker floor / video floor / pure-noise observation x
  PPO, A2C, ACKTR.

Each algorithm keeps the paper's settings (the configs' defaults) except where a profile says
otherwise (`Profile.overrides`: tiny batches for `smoke`, more envs per update for PixelMuJoCo and
Natural Atari in `quick`); every departure is written in the cell and in the report.

Natural Atari in `quick` (changed from the authors' 8 envs x 128 steps, 19,456 env steps per
seed): 256 envs per seed in 32-step rollouts, stepped in two pipelined parts of 128
(`jaxnat train --env-parts 2`), 20 updates of 8,192 env steps (163,840 per seed). In
`bench/results/atari_training.md` (a GPU with a 16-core host) that setting is the one where the
PPO loop keeps above 0.70 of the env-alone rate, one batch of 256 staying near 0.6 (measured
with 128-step rollouts; the per-step costs do not depend on the rollout's length); parts pay
only when each is large (ALE's step of one part must cover the policy's call and the host pass
of the other: at 64 envs two parts lose to one batch). The `paper` profile keeps the authors'
envs per update (PPO 8, A2C 16), so one batch (parts of 4 or 8 envs would lose); `smoke` keeps
its 2 envs in one batch.

Datasets that need a download or a registration (MNIST, CIFAR, Cityscapes) are used when found
(`root`, `$JAXNAT_DATA_DIR`, the download folder: `jaxnat.datasets.locate`); otherwise the
embedded ones stand in (Digits for MNIST, Fashion-MNIST for CIFAR-10, Clutter for Cityscapes)
and the cell says so. CIFAR-100 has no stand-in: its cells are reported as not run.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Any

from jaxnat.agents import ALGORITHMS
from jaxnat.agents.defaults import CONTINUOUS_STATE
from jaxnat.atari.games import AUTHORS_GAMES
from jaxnat.datasets import DatasetNotFoundError, locate
from jaxnat.datasets.cityscapes import find_files as cityscapes_files

if TYPE_CHECKING:
    from jaxnat.training import TrainArgs

__all__ = ["EXPERIMENTS", "CALIBRATION", "ONLY_NAMES", "CALIBRATION_STEPS", "HOST_EXPERIMENTS", "PAPER_BUDGETS", "PROFILES", "Budget", "Profile", "Cell", "Plan", "profile_variant",
           "build_grid", "dataset_choice", "data_name"]

EXPERIMENTS = ("classify", "localize", "atari", "mujoco")
# `--only calibration`: the paper profile's batch against the authors' at matched env steps
# (`_calibration_cells`); not one of the paper's experiments, so not run unless named.
CALIBRATION = "calibration"
ONLY_NAMES = (*EXPERIMENTS, CALIBRATION)
# The experiments whose cells `jaxnat train` runs on its host backend (host-batched envs: ALE
# emulates on the host's cores, the policy runs on the accelerator); the others' cells run all
# seeds in one program on the accelerator. `jaxnat reproduce` runs the two kinds side by side.
HOST_EXPERIMENTS = ("atari",)
ALGOS = ("ppo", "a2c", "acktr")
TRUNKS = {"cnn": None, "resnet18": "resnet18"}  # None: the paper's 3-layer CNN for the image size
SWEEP_WINDOWS, SWEEP_STEPS = (2, 5, 7), (10, 20, 40)
SWEEP_FIXED_M, SWEEP_FIXED_W = 20, 5
BACKGROUNDS = ("none", "noise", "video")
ROBOTS = ("Swimmer", "Ant", "HalfCheetah", "Hopper")  # the paper's figure order
OBSERVATIONS = {  # name -> PixelMuJoCo kwargs
    "checker": {"observation": "pixels", "floor": "checker"},
    "video": {"observation": "pixels", "floor": "video"},
    "noise": {"observation": "noise"},
    # The two references "noise is as good as pixels" is judged against (not in the paper): the
    # robot's state vector, and a constant observation (a policy that sees nothing: the best
    # state-independent action distribution). Both train with the pixel cells' settings
    # (`_same_settings`), not the state-vector family defaults.
    "state": {"observation": "state"},
    "constant": {"observation": "constant"},
}
PIXEL_OBSERVATIONS = ("checker", "video", "noise")  # the paper's three
DATASET_NAMES = {"mnist": "MNIST", "cifar10": "CIFAR-10", "cifar100": "CIFAR-100", "cityscapes": "Cityscapes",
                 "clutter": "Clutter"}
# dataset -> (embedded dataset, its env, its name) standing in when the dataset is not found.
STAND_INS = {"mnist": ("digits", "Classify/Digits-v0", "Digits (OpenCV's 5,000 MNIST digits)"),
             "cifar10": ("fashion_mnist", "Classify/FashionMNIST-v0", "Fashion-MNIST")}
ATARI_ALGOS = ("ppo", "a2c", "acktr", "dqn")  # the paper evaluated all four on Atari; each has a host loop
MUJOCO_ALGOS = ("ppo", "a2c")  # the two the paper's PixelMuJoCo claim names
# `jaxnat train` settings that are not algorithm config fields, allowed in `Profile.overrides`
# (and written as departures): the parts host-batched envs are stepped in, updates per evaluation.
RUN_SETTINGS = {"env_parts": 1, "eval_every": None}  # name -> the value a cell without it has (None: auto)


# The paper's env-step budget per seed of each experiment's cells, in agent steps (one `step` of
# jaxnat's env; a Natural Atari step is 4 frames at frame skip 4). The paper's text states no
# budget: these are the x-axes of its figures as the project's issue "The paper at its own
# budgets" reads them, 10M agent steps per seed for classification, localisation and
# PixelMuJoCo, and for Natural Atari 10M agent steps = 40M frames (the `num_timesteps` of the
# baselines code the authors ran counts agent steps). The report shows each finding's share.
PAPER_BUDGETS = {"classify": 10_000_000, "localize": 10_000_000, "atari": 10_000_000, "mujoco": 10_000_000}
CALIBRATION_STEPS = 2_000_000  # env steps per seed of every calibration cell (matched across batches)


@dataclasses.dataclass(frozen=True)
class Budget:
    """Env steps per seed and evaluation effort of one experiment's cells."""

    total_timesteps: int
    eval_episodes: int = 100  # test episodes per seed per evaluation (about 20 over a run; host runs: once at the end)


@dataclasses.dataclass(frozen=True)
class Profile:
    """A named size of the grid: budgets per experiment, the subsets run, overrides of settings."""

    name: str
    description: str
    seeds: int
    budgets: dict[str, Budget]
    subsets: dict[str, tuple] = dataclasses.field(default_factory=dict)  # e.g. {"games": (...)}
    overrides: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)  # experiment -> config
    env_kwargs: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)  # experiment -> make kwargs
    fast_compile: bool = False  # XLA backend optimisation off (compiles faster; for CPU smoke runs)

    def subset(self, name: str, full: tuple) -> tuple:
        return tuple(self.subsets.get(name, full))


_TINY = {"num_envs": 2, "num_steps": 8, "update_epochs": 1, "num_minibatches": 1}

# The paper profile's batch per family (changed from the authors' PPO 8 x 128, A2C 16 x 5 and
# ACKTR 32 x 20 env steps per update, which leave a GPU latency-bound: about 400 GPU-hours for
# the grid), as the calibration (`--only calibration`, `calibration.py`) cleared it: trained to
# 2M env steps per seed at the authors' batch and at 512 envs per seed, only a cell with the
# authors' optimizer steps per env step stayed inside the authors' band (docs/reproduction/paper).
# - classify: PPO at 512 envs x 32 steps with 64 minibatches (4 epochs x 64 = 256 optimizer
#   steps per 16,384 env steps: the authors' 15.6 per 1,000; at 4 minibatches it fell below the
#   band). A2C and ACKTR take one optimizer step per update, so only the authors' batch keeps
#   their steps per env step: 16 x 5 and 32 x 20 (at 512 envs both fell below, A2C with its
#   learning rate x4 too).
# - localize: the same rule (its 256x256 scenes are not calibrated separately): PPO at 128 envs
#   x 32 steps with 16 minibatches (15.6 per 1,000; at 512 envs, PPO's and ACKTR's programs asked
#   an 80 GB GPU for 74 and 50 GB), A2C and ACKTR at the authors' batch.
# - mujoco: 1,024 envs per seed (PPO 16 steps, A2C 5). PixelMuJoCo's rewards are normalised
#   (VecNormalize's return scaling, which the authors' code applies to MuJoCo) and PPO takes the
#   continuous-control settings of CleanRL / baselines (entropy 0, clip 0.2, lr 3e-4): with the
#   Atari settings and raw rewards a pixel policy is still at the untrained policy's return after
#   1M steps. The calibration runs both treatments (and the sign clipping of the authors' Atari
#   wrappers) on HalfCheetah; the profile's treatment learned most. PPO's trunk computes in
#   bfloat16 (float32 parameters and accumulation; `agents.networks`): the calibration's
#   HalfCheetah cell learned as much as in float32 at matched env steps (sitting 3), and the
#   learner is faster in it (bench/results/pixel_ppo.md). A2C stays in float32; its entropy bonus
#   (the authors' 0.01) and its batch are what the calibration's three A2C cells test.
# - atari: the authors' envs per update (PPO 8, A2C 16): ALE on the host's cores sets the cost.
_AUTHORS_BATCH = {"a2c": {"num_envs": 16, "num_steps": 5}, "acktr": {"num_envs": 32, "num_steps": 20}}
PAPER_SCALE: dict[str, dict[str, Any]] = {
    "classify": {"ppo": {"num_envs": 512, "num_steps": 32, "num_minibatches": 64}, **_AUTHORS_BATCH},
    "localize": {"ppo": {"num_envs": 128, "num_steps": 32, "num_minibatches": 16}, **_AUTHORS_BATCH},
    "mujoco": {"num_envs": 1024, "normalize_rewards": True, "eval_every": 64,
               "ppo": {"num_steps": 16, "ent_coef": 0.0, "clip_eps": 0.2, "lr": 3e-4, "dtype": "bfloat16"},
               "a2c": {"num_steps": 5}},
}
# The batch the paper profile's first sitting trained classification at (512 envs per seed, each
# algorithm's own rollout length, PPO at 4 minibatches): the calibration's "512 envs" cells.
_LARGE_BATCH = {"num_envs": 512, "ppo": {"num_steps": 32}, "a2c": {"num_steps": 5}, "acktr": {"num_steps": 20}}

PROFILES: dict[str, Profile] = {
    "smoke": Profile(
        name="smoke",
        description="every cell type end to end with tiny budgets, on a CPU in minutes (CI runs it)",
        seeds=2,
        budgets={e: Budget(total_timesteps=32, eval_episodes=4) for e in ONLY_NAMES},
        subsets={"datasets": ("mnist",), "algos": ("ppo",), "trunks": ("cnn",), "sweep": ((2, 20),),
                 "localize": ("clutter",), "games": ("Breakout",), "backgrounds": ("video",),
                 "atari_algos": ("ppo",), "robots": ("Swimmer",), "observations": ("noise",),
                 "mujoco_algos": ("a2c",), "calibration": ("classify",), "calibration_algos": ("ppo",),
                 "calibration_variants": ("authors", "512 envs, optimizer steps restored")},
        overrides={e: dict(_TINY) for e in ONLY_NAMES},
        # Short episodes: a smoke run's evaluation plays whole episodes.
        env_kwargs={"localize": {"M": 10, "image_size": 64}, "atari": {"max_episode_steps": 20},
                    "mujoco": {"max_steps_in_episode": 10}},
        fast_compile=True,
    ),
    "quick": Profile(
        name="quick",
        description="every finding with reduced budgets, for one sitting on one GPU",
        seeds=5,
        budgets={"classify": Budget(150_000, eval_episodes=200),
                 "localize": Budget(100_000, eval_episodes=100),
                 "atari": Budget(163_840, eval_episodes=2),  # 20 updates of 256 envs x 32 steps
                 "mujoco": Budget(262_144, eval_episodes=5),  # 64 updates of 128 envs x 32 steps
                 "calibration": Budget(CALIBRATION_STEPS)},
        # The 3-layer CNN only: a ResNet-18 cell takes minutes even at this budget (its claims
        # are judged by the paper profile). Natural Atari: one game, the backgrounds of the
        # finding (none vs natural video); an Atari cell takes about 3 minutes (5 seeds in turn).
        subsets={"datasets": ("mnist", "cifar10"), "trunks": ("cnn",), "localize": ("clutter",),
                 "games": ("Breakout",), "backgrounds": ("none", "video"), "atari_algos": ("ppo",),
                 "robots": ("HalfCheetah",), "observations": ("checker", "noise"), "mujoco_algos": ("ppo",)},
        # PixelMuJoCo: 128 envs per update in 32-step rollouts (the paper: 8 x 128), as the
        # physics is latency-bound at a few dozen envs, and the evaluation (1,000-step episodes,
        # latency-bound too) every 32 updates, not ~20 times (the figures plot training returns). Natural Atari: 256 envs in two
        # pipelined parts (the module's docstring says why), 32 steps per update for as many
        # updates as 8 x 128 gave.
        overrides={"mujoco": {"num_envs": 128, "num_steps": 32, "eval_every": 32},
                   "atari": {"num_envs": 256, "num_steps": 32, "env_parts": 2}},
        # Test play ends after 2,000 agent steps (8,000 frames): an untrained greedy policy that never
        # serves would otherwise play to Atari's 27,000-step limit. PixelMuJoCo: MJX with the
        # robot's `physics="fast"` settings (fewer solver iterations; its distance from Gymnasium's
        # dynamics is measured in bench/results/mjx_fidelity.md).
        env_kwargs={"atari": {"max_episode_steps": 2000}, "mujoco": {"physics": "fast"}},
    ),
    "paper": Profile(
        name="paper",
        description="the paper's budgets (10M agent steps per seed) at GPU scale; run piecewise with --only, resumable",
        seeds=5,
        budgets={"classify": Budget(10_000_000, eval_episodes=1000),
                 "localize": Budget(10_000_000, eval_episodes=1000),
                 "atari": Budget(PAPER_BUDGETS["atari"], eval_episodes=10),  # 40M frames
                 "mujoco": Budget(10_000_000, eval_episodes=10),
                 "calibration": Budget(CALIBRATION_STEPS, eval_episodes=200)},
        subsets={"mujoco_algos": MUJOCO_ALGOS},
        overrides=PAPER_SCALE,
        # PixelMuJoCo: MJX with the robot's `physics="fast"` settings, as in `quick`.
        env_kwargs={"mujoco": {"physics": "fast"}},
    ),
}


@dataclasses.dataclass(frozen=True)
class Cell:
    """One training run of the grid, written to `<out>/<name>/` by `jaxnat train`'s trainer."""

    name: str
    experiment: str  # one of EXPERIMENTS (the --only names)
    figure: str  # the paper figure the cell belongs to (report.FIGURES)
    env_id: str | None  # None: not runnable here (`skip` says why)
    env_kwargs: dict
    algo: str
    trunk: str | None
    budget: Budget
    overrides: dict  # config fields set on top of the algorithm's defaults
    labels: dict  # what the report groups by: dataset, trunk, w, M, game, background, robot, observation
    note: str = ""  # a stand-in dataset, or another departure from the paper
    skip: str = ""  # why the cell cannot run on this machine ("" = runnable)

    @property
    def host(self) -> bool:
        """Whether the cell trains on the host backend (`HOST_EXPERIMENTS`)."""
        return self.experiment in HOST_EXPERIMENTS

    def train_args(self, seeds: int, run_dir, *, resume: bool = False) -> TrainArgs:
        """The arguments `jaxnat.training.train` runs this cell with: a new run into `run_dir`,
        or (`resume`) the run there continued. They are what `jaxnat.training.parse_args` makes
        of the cell's `jaxnat train` command line, `given` included (the arguments it names:
        with `--resume`, one given at its default value must still match the run's)."""
        from jaxnat.training import ConfigOverrides, TrainArgs

        fields = {"env_id": self.env_id, "algo": self.algo, "seeds": seeds,
                  "total_timesteps": self.budget.total_timesteps, "eval_episodes": self.budget.eval_episodes,
                  "resume" if resume else "run_dir": Path(run_dir)}
        if self.env_kwargs:  # as given on a command line: `KEY=VALUE` texts, read by the trainer
            fields["env_kwargs"] = tuple(f"{k}={v}" for k, v in self.env_kwargs.items())
        if self.trunk is not None:
            fields["trunk"] = self.trunk
        top, config = {f.name for f in dataclasses.fields(TrainArgs)}, {}
        for key, value in self.overrides.items():  # run settings (num_envs, env_parts, ...) or config fields
            (fields if key in top else config)[key] = value
        return TrainArgs(**fields, config=ConfigOverrides(**config), given=tuple(sorted({*fields, *config})))


def _settings(algo: str, overrides: dict) -> dict:
    """The profile's overrides that are settings of `algo` (e.g. epochs only for PPO), and the
    run settings of `jaxnat train` (`RUN_SETTINGS`): the shared ones, then `overrides[algo]`."""
    fields = {f.name for f in dataclasses.fields(ALGORITHMS[algo].config)} | set(RUN_SETTINGS)
    merged = {**overrides, **overrides.get(algo, {})}
    return {k: v for k, v in merged.items() if k in fields}


def _same_settings(algo: str, settings: dict) -> dict:
    """`settings` of a pixel cell made explicit for a cell with a vector observation, which
    would otherwise take the state-vector family defaults (`agents.defaults.CONTINUOUS_STATE`:
    other batch, epochs, learning rate): every field those defaults set, and the reward
    treatment, at the pixel cell's value. Observation normalisation stays the vector's own
    (derived from the observation, as the trunk is), and so does the computation dtype: float32,
    since a small MLP gains no speed from bfloat16 and float32 is the stronger reference."""
    config = ALGORITHMS[algo].config()
    fields = [*CONTINUOUS_STATE.get(algo, {}), "normalize_rewards", "clip_rewards"]
    same = {k: settings.get(k, getattr(config, k)) for k in fields if hasattr(config, k)}
    same["normalize_rewards"] = bool(same.get("normalize_rewards"))  # None: off, as for images
    vector = {"dtype": "float32"} if "dtype" in settings else {}
    return {**same, **settings, **vector}


def _found(check) -> bool:
    try:
        check()
    except (DatasetNotFoundError, OSError, ValueError):
        return False
    return True


def _files_found(name: str) -> bool:
    return _found(lambda: (locate.find(name, "train"), locate.find(name, "test")))


def dataset_choice(dataset: str) -> tuple[str | None, str, str]:
    """`(env id or None, note, skip reason)` for a paper dataset: the real one when its files are
    found, else the embedded stand-in (noted), else None with the reason."""
    real = {"mnist": "Classify/MNIST-v0", "cifar10": "Classify/CIFAR10-v0", "cifar100": "Classify/CIFAR100-v0",
            "cityscapes": "Localize/Cityscapes-v0", "clutter": "Localize/Clutter-v0"}[dataset]
    if dataset == "clutter":  # built from opencv-doc's photos and videos, the digits and Fashion-MNIST
        from jaxnat.natural.clutter import background_files

        if _found(background_files) and _files_found("digits") and _files_found("fashion_mnist"):
            return real, "", ""
        return None, "", ("Clutter's sources not found (opencv-doc's photos and videos, its digits and "
                          "dataset-fashion-mnist: `make data`)")
    if dataset == "cityscapes":
        if _found(lambda: (cityscapes_files("train"), cityscapes_files("test"))):
            return real, "", ""
        return None, "", "Cityscapes not found (needs a registration; see jaxnat.datasets.cityscapes)"
    if _files_found(dataset):
        return real, "", ""
    how = f"jaxnat.datasets.download({dataset!r})"
    if dataset in STAND_INS:
        name, env_id, label = STAND_INS[dataset]
        if _files_found(name):
            return env_id, f"{label} stands in for {DATASET_NAMES[dataset]} (not found; {how})", ""
    return None, "", f"{DATASET_NAMES[dataset]} not found and no embedded stand-in ({how})"


def _vision_cells(profile: Profile, experiment: str, datasets: tuple[str, ...], noise_dataset: str) -> list[Cell]:
    """The dataset x trunk x algorithm cells of a vision experiment, and its noise control (PPO
    with the 3-layer CNN from pure noise, which the paper did not run) on `noise_dataset`."""
    budget, extra = profile.budgets[experiment], profile.overrides.get(experiment, {})
    cells = []
    for dataset in datasets:
        env_id, note, skip = dataset_choice(dataset)
        for trunk in profile.subset("trunks", tuple(TRUNKS)):
            for algo in profile.subset("algos", ALGOS):
                cells.append(Cell(f"{experiment}-{data_name(dataset, note)}-{trunk}-{algo}", experiment,
                                  f"{experiment}-{trunk}", env_id, {}, algo, TRUNKS[trunk], budget,
                                  _settings(algo, extra), {"dataset": dataset, "trunk": trunk}, note, skip))
    env_id, note, skip = dataset_choice(noise_dataset)
    cells.append(Cell(f"{experiment}-{data_name(noise_dataset, note)}-cnn-ppo-noise", experiment, "noise-control",
                      env_id, {"observation_noise": True}, "ppo", None, budget, _settings("ppo", extra),
                      {"dataset": noise_dataset, "trunk": "cnn", "observation": "noise"}, note, skip))
    return cells


def data_name(dataset: str, note: str) -> str:
    """The name of the data a cell trains on, for its name: the stand-in's when `note` says one
    stands in (`dataset_choice`), so that a cell trained on Digits is never named after MNIST.
    The cell's `labels["dataset"]` keeps the paper's dataset: the role the findings read."""
    return STAND_INS[dataset][0].replace("_", "") if note and dataset in STAND_INS else dataset


def _classify_cells(profile: Profile) -> list[Cell]:
    datasets = profile.subset("datasets", ("mnist", "cifar10", "cifar100"))
    cells = _vision_cells(profile, "classify", datasets, datasets[0])
    budget, extra = profile.budgets["classify"], profile.overrides.get("classify", {})
    env_id, note, skip = dataset_choice("cifar10")
    sweep = [(w, SWEEP_FIXED_M) for w in SWEEP_WINDOWS] + [(SWEEP_FIXED_W, m) for m in SWEEP_STEPS]
    for w, m in dict.fromkeys(profile.subset("sweep", tuple(sweep))):
        # The params' own names (not the constructor's w=, M=): the sweep's cells then differ only
        # in traced params and share compiled programs (`training.device_backend.compiled_program`).
        cells.append(Cell(f"classify-sweep-w{w}-M{m}", "classify", "sweep", env_id,
                          {"window": w, "max_steps_in_episode": m}, "ppo",
                          None, budget, _settings("ppo", extra), {"dataset": "cifar10", "w": w, "M": m}, note, skip))
    return cells


def _localize_cells(profile: Profile) -> list[Cell]:
    return _vision_cells(profile, "localize", profile.subset("localize", ("cityscapes", "clutter")), "clutter")


def _atari_cells(profile: Profile) -> list[Cell]:
    budget, extra = profile.budgets["atari"], profile.overrides.get("atari", {})
    cells = []
    for game in profile.subset("games", AUTHORS_GAMES):
        for background in profile.subset("backgrounds", BACKGROUNDS):
            for algo in profile.subset("atari_algos", ATARI_ALGOS):
                cells.append(Cell(f"atari-{game.lower()}-{background}-{algo}", "atari", "atari",
                                  # "none" is the env's default: left out, as a user would
                                  f"NaturalAtari/{game}-v0", {} if background == "none" else {"background": background},
                                  algo, None, budget,
                                  _settings(algo, extra), {"game": game, "background": background}))
    return cells


def _mujoco_cells(profile: Profile) -> list[Cell]:
    budget, extra = profile.budgets["mujoco"], profile.overrides.get("mujoco", {})
    cells = []
    for robot in profile.subset("robots", ROBOTS):
        for observation in profile.subset("observations", tuple(OBSERVATIONS)):
            for algo in profile.subset("mujoco_algos", MUJOCO_ALGOS):
                settings = _settings(algo, extra)
                if observation not in PIXEL_OBSERVATIONS:
                    settings = _same_settings(algo, settings)
                cells.append(Cell(f"mujoco-{robot.lower()}-{observation}-{algo}", "mujoco", "mujoco",
                                  f"PixelMuJoCo/{robot}-v0", dict(OBSERVATIONS[observation]), algo, None, budget,
                                  settings, {"robot": robot, "observation": observation}))
    return cells


# The calibration's settings per group: (algo, variant, settings[, env kwargs added to the
# group's env's, `CALIBRATION_ENVS`]). "authors": their envs per
# update (pytorch-a2c-ppo-acktr's Atari settings); "512 envs": the first sitting's batch
# (`_LARGE_BATCH`); the others restore optimizer steps per env step, or change the reward
# treatment. Each group's cells are judged against its "authors" cell of the same algorithm
# (`calibration.py`); the variant the profile trains at is `profile_variant`'s.
# PixelMuJoCo's group compares reward treatments at the profile's batch: its authors' batch (8
# envs of 84x84 renders) is latency-bound, hours at 2M steps x 5 seeds, left for a later sitting.
_LARGE_PPO, _MUJOCO_PPO = _settings("ppo", _LARGE_BATCH), _settings("ppo", PAPER_SCALE["mujoco"])
_MUJOCO_A2C = _settings("a2c", PAPER_SCALE["mujoco"])
_MUJOCO_F32 = {**_MUJOCO_PPO, "dtype": "float32"}  # the reward treatments were calibrated in float32
_ATARI_PPO = {"ent_coef": 0.01, "clip_eps": 0.1, "lr": 2.5e-4}  # PPOConfig's defaults: the paper's
CALIBRATION_VARIANTS: dict[str, list[tuple[str, str, dict[str, Any]]]] = {
    "classify": [
        ("ppo", "authors", {"num_envs": 8, "num_steps": 128}),
        ("ppo", "64 envs", {"num_envs": 64, "num_steps": 128}),
        ("ppo", "512 envs", _LARGE_PPO),
        # 64 minibatches of 256 x 4 epochs: the authors' optimizer steps per env step (15.6 per 1,000)
        ("ppo", "512 envs, optimizer steps restored", {**_LARGE_PPO, "num_minibatches": 64}),
        ("a2c", "authors", dict(_AUTHORS_BATCH["a2c"])),
        ("a2c", "64 envs", {"num_envs": 64, "num_steps": 5}),
        ("a2c", "512 envs", _settings("a2c", _LARGE_BATCH)),
        # A2C takes one optimizer step per update: the learning rate is its only lever at a batch
        # 32x the authors' (x4: between the square-root and the linear scaling rule).
        ("a2c", "512 envs, lr x4", {**_settings("a2c", _LARGE_BATCH), "lr": 2.8e-3}),
        ("acktr", "authors", dict(_AUTHORS_BATCH["acktr"])),
        ("acktr", "512 envs", _settings("acktr", _LARGE_BATCH)),
    ],
    "mujoco": [
        ("ppo", "profile", _MUJOCO_PPO),
        # The profile's settings with the trunk in float32: does the faster bfloat16 learner
        # (bench/results/pixel_ppo.md) learn the same? The reward treatments below are float32's.
        ("ppo", "profile in float32", _MUJOCO_F32),
        ("ppo", "Atari settings, sign-clipped rewards", {**_MUJOCO_F32, **_ATARI_PPO, "normalize_rewards": False,
                                                          "clip_rewards": True}),
        ("ppo", "Atari settings, normalised rewards", {**_MUJOCO_F32, **_ATARI_PPO}),
        ("ppo", "sign-clipped rewards", {**_MUJOCO_F32, "normalize_rewards": False, "clip_rewards": True}),
        # The profile's settings with MuJoCo Warp stepping the physics (`physics_impl="warp"`,
        # faster from pixels: bench/results/pixel_ppo.md): does a policy learn the same as
        # with MJX's JAX implementation, which the profile's PixelMuJoCo cells train on?
        ("ppo", "profile, MuJoCo Warp physics", _MUJOCO_PPO, {"physics_impl": "warp"}),
        # A2C from pixels keeps the authors' entropy bonus (0.01) at 64x their batch (1,024 envs
        # x 5 steps). HalfCheetah's pixel A2C cells ended below their untrained policy in sitting 9
        # (SITTINGS.md), where its state cell learned. Two suspects, one cell each: the bonus
        # (does the Gaussian stay narrow enough without it?) and the batch (classification's A2C
        # collapsed at 512 envs; 128 envs is 8x the authors', whose own 16 are hours from pixels).
        ("a2c", "profile", _MUJOCO_A2C),
        ("a2c", "no entropy bonus", {**_MUJOCO_A2C, "ent_coef": 0.0}),
        ("a2c", "128 envs", {**_MUJOCO_A2C, "num_envs": 128}),
    ],
}


def profile_variant(group: str, algo: str) -> str | None:
    """The calibration variant of `group` and `algo` whose settings are the paper profile's
    (`PAPER_SCALE`), None if none is."""
    wanted = _settings(algo, PAPER_SCALE[group])
    return next((variant for a, variant, settings, *env in CALIBRATION_VARIANTS.get(group, [])
                 if a == algo and settings == wanted and not env), None)


CALIBRATION_ENVS = {"mujoco": ("PixelMuJoCo/HalfCheetah-v0", {"observation": "pixels", "floor": "checker",
                                                               "physics": "fast"})}


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in text.lower()).strip("-").replace("--", "-")


def _calibration_cells(profile: Profile) -> list[Cell]:
    """The calibration: each group's cell at the authors' batch, at the paper profile's, and at
    the variants between, all to `CALIBRATION_STEPS` env steps per seed (the profile's budget
    and overrides apply on top: the smoke profile's tiny batch)."""
    budget, extra = profile.budgets[CALIBRATION], profile.overrides.get(CALIBRATION, {})
    env_id, note, skip = dataset_choice("mnist")
    cells = []
    for group in profile.subset("calibration", tuple(CALIBRATION_VARIANTS)):
        group_env, kwargs = CALIBRATION_ENVS.get(group, (env_id, {}))
        for algo, variant, settings, *env in CALIBRATION_VARIANTS[group]:
            if algo not in profile.subset("calibration_algos", ALGOS) or \
                    variant not in profile.subset("calibration_variants", (variant,)):
                continue
            settings = {**settings, **_settings(algo, extra)}
            cells.append(Cell(f"calibration-{group}-{algo}-{_slug(variant)}", CALIBRATION, CALIBRATION, group_env,
                              {**kwargs, **(env[0] if env else {})}, algo, None,
                              dataclasses.replace(budget, eval_episodes=min(budget.eval_episodes, 10))
                              if group == "mujoco" else budget, _settings(algo, settings),
                              {"group": group, "variant": variant, **({"dataset": "mnist"} if group == "classify" else {})},
                              note if group == "classify" else "", skip if group == "classify" else ""))
    return cells


_BUILDERS = {"classify": _classify_cells, "localize": _localize_cells, "atari": _atari_cells,
             "mujoco": _mujoco_cells, CALIBRATION: _calibration_cells}


def build_grid(profile: Profile, only: tuple[str, ...] = EXPERIMENTS) -> list[Cell]:
    """The cells of `profile` for the experiments in `only` (`ONLY_NAMES`), in the paper's
    order, the calibration last."""
    cells = [cell for experiment in ONLY_NAMES if experiment in only for cell in _BUILDERS[experiment](profile)]
    return [dataclasses.replace(cell, env_kwargs={**cell.env_kwargs, **profile.env_kwargs[cell.experiment]})
            if cell.experiment in profile.env_kwargs else cell for cell in cells]


@dataclasses.dataclass(frozen=True)
class Plan:
    """What one `jaxnat reproduce` trains and reports: the `cells` of `profile` for the
    experiments in `only`, each with `seeds` seeds, in `out` (`command.make_plan` builds it)."""

    profile: Profile
    only: tuple[str, ...]
    seeds: int
    out: Path
    cells: list[Cell]
