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
	$(PYTHON) scripts/train.py experiment=demo

train: $(STAMP)
	$(PYTHON) scripts/train.py $(ARGS)

clean:
	rm -rf outputs multirun .pytest_cache

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
