# flock_torchrl — every target sets itself up from nothing (a local venv in .venv).
PY      ?= python3
VENV    ?= .venv
PYTHON  := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
# torch first, pinned to the CPU build that lies on this kind of machine; the package's
# range admits it, so pip keeps it (and keeps a user's own CUDA build in their own env).
TORCH   ?= torch==2.13.0

.PHONY: install test test-all demo train train-all reproduce-table3 reproduce-table4 reproduce-table5 \
        figures benchmark tune-baselines clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(PYTHON) -m pip install --quiet --upgrade pip
	$(PYTHON) -m pip install --quiet "$(TORCH)"
	$(PYTHON) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(PYTHON) -m pytest -n 2 --dist loadfile -m "not slow"

test-all: $(STAMP)
	$(PYTHON) -m pytest -n 2 --dist loadfile

# The main job on a small embedded default: train Policy3-G (the paper's method) briefly,
# then evaluate it on the training scenario.
demo: $(STAMP)
	$(PYTHON) scripts/train.py experiment=demo resume=auto

train: $(STAMP)
	$(PYTHON) scripts/train.py $(ARGS)

# The shipped checkpoints: the ten learned policies (seed 0) and Policy3-G seeds 1-2 with
# experiment=fast, two single-threaded runs at a time, then the slim policies into checkpoints/.
LEARNED := policy1,policy1_g,policy2,policy2_g,policy3,policy3_g,policy4_g,policy5_g,policyd_g,policyp_g
train-all: $(STAMP)
	OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py -m hydra/launcher=local experiment=fast progress=false \
		resume=auto seed=0 policy=$(LEARNED)
	OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py -m hydra/launcher=local experiment=fast progress=false \
		resume=auto seed=1,2 policy=policy3_g
	$(PYTHON) scripts/export_checkpoints.py runs/fast

# Paper reproduction from the shipped checkpoints (checkpoints/) and the two baselines.
EPISODES ?= 500
reproduce-table3: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=3 episodes=$(EPISODES)

reproduce-table4: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=4 episodes=$(EPISODES)

reproduce-table5: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=5 episodes=$(EPISODES)

figures: $(STAMP)
	$(PYTHON) scripts/figures.py

tune-baselines: $(STAMP)
	$(PYTHON) scripts/tune_baselines.py

benchmark: $(STAMP)
	$(PYTHON) scripts/benchmark.py
