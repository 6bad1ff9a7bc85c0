"""The training command `jaxnat train` (also `python -m jaxnat.train`): train PPO, A2C, ACKTR or DQN on a jaxnat env over many seeds.

    jaxnat train                                   # PPO on Classify/Digits-v0, 5 seeds
    jaxnat train --env-id Classify/MNIST-v0 --algo a2c --lr 1e-3 --env-kwargs w=3 M=10
    jaxnat train --resume runs/Classify_Digits-v0-ppo-20250101-120000

All seeds train at once (`jit(vmap(...))` over their keys). Training runs in chunks of
`--eval-every` updates, each one compiled `lax.scan`; after every chunk all seeds are scored on
the test split (the same env id with `split="test"` when the env has splits), and the run
directory gets:

- `config.json`   env id and kwargs, algorithm, the full resolved config, seeds, versions
- `metrics.jsonl` one line per update per seed: update, env_steps, seed, training metrics
- `eval.jsonl`    one line per evaluation per seed: greedy/sampled test return, accuracy
                  (terminated fraction), length; chunk timing
- `curve.png`     mean +- std over seeds vs env steps: returns, and train/test accuracy
- `checkpoints/`  orbax checkpoints of the vmapped `RunnerState` (last 2 kept)
- `summary.json`  the final table: mean +- std over seeds

`--resume RUN_DIR` restores the latest checkpoint and finishes the run; because the runner
state carries the PRNG keys, the result is bit-for-bit that of an uninterrupted run.
"""

from jaxnat.training.args import ConfigOverrides, TrainArgs, TrainError, parse_args, parse_env_kwargs
from jaxnat.training.checkpoints import load_checkpoint
from jaxnat.training.loop import TrainResult, main, train
from jaxnat.training.spec import RunSpec

__all__ = ["TrainArgs", "ConfigOverrides", "RunSpec", "TrainResult", "TrainError", "train",
           "load_checkpoint", "main", "parse_args", "parse_env_kwargs"]
