"""The training command `jaxnat train` (also `python -m jaxnat.train`): train PPO, A2C, ACKTR or
DQN on a jaxnat env over many seeds, into a run directory (`config.json`, `metrics.jsonl`,
`eval.jsonl`, `curve.png`, `checkpoints/`, `summary.json`; `docs/api.md` says what each holds).

    jaxnat train                                   # PPO on Classify/Digits-v0, 5 seeds
    jaxnat train --env-id Classify/MNIST-v0 --algo a2c --lr 1e-3 --env-kwargs w=3 M=10
    jaxnat train --resume runs/Classify_Digits-v0-ppo-20250101-120000

`chunk_loop.py` is the one loop, over a backend: `device_backend.DeviceBackend` trains every seed at once
in one compiled program (`jit(vmap(...))` over their keys) and resumes bit for bit (the state
carries the PRNG keys), on one device or split over several (`--devices`, `placement.py`);
`host_backend.HostBackend` trains host-batched envs (Natural Atari: every seed side by side on one
batch of emulators, or one seed after another).
"""

from jaxnat.training.args import ConfigOverrides, TrainArgs, TrainError, parse_args, parse_env_kwargs
from jaxnat.training.checkpoints import load_checkpoint
from jaxnat.training.command import TrainResult, main, prepare_programs, train
from jaxnat.training.placement import make_sharded_train
from jaxnat.training.rundir import RunRecord, read_run, run_status
from jaxnat.training.spec import RunSpec
from jaxnat.training.strengths import make_strength_train

__all__ = ["TrainArgs", "ConfigOverrides", "RunSpec", "TrainResult", "TrainError", "train",
           "load_checkpoint", "main", "prepare_programs", "make_sharded_train", "make_strength_train", "parse_args", "parse_env_kwargs", "RunRecord", "read_run", "run_status"]
