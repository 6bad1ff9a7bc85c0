# `make run` and `make test` each set everything up on a fresh machine (idempotent, fast the
# second time), then run the main job / the test suite.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
EXTRAS ?= dev,agents,gym,video,atari,mujoco,warp
STAMP := $(VENV)/.jaxnat-installed

.PHONY: setup data run demo test bench clean

setup: $(STAMP) data

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check --upgrade pip
	$(PY) -m pip install -q --disable-pip-version-check -e '.[$(EXTRAS)]'
	@touch $@

data:
	@bash scripts/install_data.sh

# The main job: PPO on the real handwritten digits, 5 seeds at once, evaluated on the test split.
# Sized to finish well inside 5 minutes on a 2-core CPU: 66 updates of 32 envs x 32 steps per
# seed, 4 epochs x 8 minibatches (the most learning per CPU second in bench/results/ppo_sweep.md),
# and a 7x7 window, with which the greedy policy beats a random one in this budget (at the
# paper's w=5 it does not yet: bench/results/main_job.md).
MAIN_JOB ?= --env-id Classify/Digits-v0 --env-kwargs w=7 --algo ppo --seeds 5 --total-timesteps 67584 \
	--num-envs 32 --num-steps 32 --update-epochs 4 --num-minibatches 8 --lr 1e-3 \
	--eval-every 22 --eval-episodes 200 --run-dir out/main-$$(date +%Y%m%d-%H%M%S)

run: setup
	$(PY) -m jaxnat.train $(MAIN_JOB)

# A random policy over 4,096 vmapped envs: throughput and the chance-level return.
demo: setup
	$(PY) -m jaxnat.demo

test: setup
	JAX_PLATFORMS=cpu $(PY) -m pytest -q -n 2 --dist loadgroup

bench: setup
	$(PY) bench/classify_throughput.py

clean:
	rm -rf $(VENV) out .pytest_cache
