# flock_torchrl — every target sets itself up from nothing (a local venv in .venv).
PY      ?= python3
VENV    ?= .venv
PYTHON  := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
# torch first, pinned to the CPU build that lies on this kind of machine; the package's
# range admits it, so pip keeps it (and keeps a user's own CUDA build in their own env).
TORCH   ?= torch==2.13.0
# READING=literal|paper_fit picks a reading; empty: the default of conf/world.yaml.
READING ?=
R_ARG   := $(if $(READING),reading=$(READING),)
EPISODES ?= 500
# Several training runs, two single-threaded ones at a time (Hydra's joblib launcher, conf/hydra/launcher/local.yaml),
# each into the folder a single run of it would use under $(RUNS)/, a killed sweep continuing where it stopped (resume=auto).
SWEEP   := OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py -m hydra/launcher=local progress=false resume=auto
# The publications (the targets that write results/, figures/ and the documents' spliced blocks) and the targets
# that run several apps: scripts/publish.py <target> (flock_torchrl/report/publish.py; what each flies is data,
# conf/publish.yaml). A publication writes its files aside, then lands them with results/standing.md and the
# documents' copies as one set: a Ctrl-C at any moment leaves the old set or the whole new one.
PUBLISH := OMP_NUM_THREADS=1 $(PYTHON) scripts/publish.py

.PHONY: install test test-all demo readme-demo docs train train-all check-train-all train-paper train-paper-all train-paper-populations \
        train-fast-populations train-mixed ship-checkpoints reproduce-table3 reproduce-table3-paper \
        figures publish publish-tables publish-paper-recipe publish-scaling publish-claims tune-baselines benchmark publish-benchmark \
        scaling train-3d train-3d-scaling ship-threed table3-3d publish-threed clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV) && $(PYTHON) -m pip install --quiet --upgrade pip
	$(PYTHON) -m pip install --quiet "$(TORCH)"
	$(PYTHON) -m pip install --quiet -e ".[test]" && touch $(STAMP)

install: $(STAMP)

# The fast default: every test file, leaving out the tests marked slow (process-level signals,
# the wheel, Optuna, long equivalence runs, trainings of more than a few seconds).
test: $(STAMP)
	$(PYTHON) -m pytest -n 2 --dist loadfile -m "not slow"

# Every test, the slow ones included (what CI runs: .ci/run).
test-all: $(STAMP)
	$(PYTHON) -m pytest -n 2 --dist loadfile

# The main job on a small embedded default: train Policy3-G (the paper's method) for a fixed
# number of frames, then evaluate it. Re-running it changes nothing (resume=auto) and says which
# finished run it shows.
demo: $(STAMP)
	$(PYTHON) scripts/train.py experiment=demo resume=auto $(R_ARG)

# README's demo lines, written by the demo itself: train it from nothing in outputs/readme_demo/
# (what a fresh clone's `make demo` does), keep its checkpoint and evaluation lines with this
# machine's name in docs/demo.md, and splice them into README.md (the two land together).
readme-demo: $(STAMP)
	$(PUBLISH) readme-demo

# The documents' copies of results/ (docs/results.md's spliced blocks, README's "Where it stands"
# written from results/ into results/standing.md), refreshed from results/; every publish target
# refreshes them with its own files, landing together (scripts/publish.py, conf/publish.yaml).
docs: $(STAMP)
	$(PUBLISH) docs

train: $(STAMP)
	$(PYTHON) scripts/train.py $(R_ARG) $(ARGS)

# The ten learned policies, three seeds each, experiment=fast, into $(RUNS)/fast/<reading>/.
# Eager: at B = 32 the compiled step recompiles for each policy's world
# (10-25 s each), more than it saves; the compiled loss does not pay at minibatch 1280.
LEARNED := policy1,policy1_g,policy2,policy2_g,policy3,policy3_g,policy4_g,policy5_g,policyd_g,policyp_g
SEEDS   ?= 0,1,2
RUNS    ?= runs
train-all: $(STAMP)
	$(SWEEP) experiment=fast seed=$(SEEDS) policy=$(LEARNED) hydra.sweep.dir=$(RUNS) $(R_ARG) $(ARGS)

# `make train-all` timed from nothing into outputs/train_all/<reading>/ (runs/, then its shipped
# policies in checkpoints/), then its Table III (500 episodes per seed) written there beside the
# shipped one, results/<reading>/table3.csv: table3_vs_reference.md says, per policy, whether
# success stays within 1 point and d_min_uav within 0.1 m. Refuses a folder that exists.
CHECK_READING := $(or $(READING),paper_fit)
CHECK   ?= outputs/train_all/$(CHECK_READING)
ROWS    ?= Policy1,Policy1-G,Policy2,Policy2-G,Policy3,Policy3-G,Policy4-G,Policy5-G,PolicyD-G,PolicyP-G
check-train-all: $(STAMP)
	$(PUBLISH) check-train-all check_train_all.folder=$(CHECK) check_train_all.reading=$(CHECK_READING) check_train_all.seeds=$(SEEDS) check_train_all.policies=$(LEARNED) check_train_all.rows=$(ROWS) episodes=$(EPISODES)

# The paper's own recipe (Table I, one env, one update per step, 5000 episodes) for Policy3-G.
train-paper: $(STAMP)
	OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py experiment=paper policy=policy3_g seed=0 progress=false compile=true resume=auto $(R_ARG)

# The paper's recipe for the policies Table III's claims rest on, under paper_fit (about 3.5 hours a run
# here): seed 0 of eight policies (Policy3-G's seed 0 is `make train-paper`'s run: a finished one is reused),
# then seeds 1 and 2 of Policy3-G, 4-G and 5-G.
PAPER_SEED0 := policy1,policy1_g,policy2,policy2_g,policy3,policy3_g,policy4_g,policy5_g
PAPER_MORE  := policy3_g,policy4_g,policy5_g
train-paper-all: $(STAMP)
	$(SWEEP) experiment=paper reading=paper_fit compile=true policy=$(PAPER_SEED0) seed=0 hydra.sweep.dir=$(RUNS)
	$(SWEEP) experiment=paper reading=paper_fit compile=true policy=$(PAPER_MORE) seed=1,2 hydra.sweep.dir=$(RUNS)

# Ten seeds of a policy as one population (docs/population.md): seeds 0-9 of the eight policies the
# paper's claims rest on, under the paper's recipe (paper_fit), two populations at a time, each
# resuming where it stopped (resume=auto), their update eager (a population vmaps its loss: compile=false, what
# their runs recorded); then the nine off-policy learners under `fast`.
# PolicyP-G (PPO) trains no population: its ten fast seeds are `make train-all SEEDS=0,...,9 LEARNED=policyp_g`.
POPULATION ?= 10
PAPER_POPULATIONS := policy3_g,policy3,policy1_g,policy1,policy2_g,policy2,policy4_g,policy5_g
FAST_POPULATIONS  := policy1,policy1_g,policy2,policy2_g,policy3,policy3_g,policy4_g,policy5_g,policyd_g
train-paper-populations: $(STAMP)
	$(SWEEP) experiment=paper reading=paper_fit compile=false policy=$(PAPER_POPULATIONS) seed=0 population=$(POPULATION) hydra.sweep.dir=$(RUNS)

# POP_SEED: the first member's seed (literal's shipped seeds 3-9: POPULATION=7 POP_SEED=3).
POP_SEED ?= 0
train-fast-populations: $(STAMP)
	$(SWEEP) experiment=fast policy=$(FAST_POPULATIONS) seed=$(POP_SEED) population=$(POPULATION) hydra.sweep.dir=$(RUNS) $(R_ARG)

# One Policy3-G trained on 5, 20 and 50 UAVs at once (experiment=mixed), three seeds, two at a time.
train-mixed: $(STAMP)
	$(SWEEP) experiment=mixed policy=policy3_g seed=$(SEEDS) hydra.sweep.dir=$(RUNS) $(R_ARG)

# The named step that updates checkpoints/ (slim policies of the finished runs, per reading: each
# reading's collections and manifests land whole or not at all).
ship-checkpoints: $(STAMP)
	$(PYTHON) scripts/ship.py reading=literal
	$(PYTHON) scripts/ship.py reading=paper_fit

# The paper's tables and figures from checkpoints/ and the baselines, into outputs/.
# Table III also goes cell by cell beside the shipped results/<reading>/table3.csv: on another
# machine (CPU, instruction set, thread count) float round-off differs, so each cell is judged
# within REPRODUCE_TOLERANCE (rates 2 points, closest distances 0.05 m, d_c 0.1 m, speed 0.02 m/s,
# t_goal 0.5 s: two to six times the largest difference measured between two CPUs;
# docs/decisions.md, "Reproducibility"); only EPISODES=500 is comparable with the shipped table.
REPRODUCE_TOLERANCE := {success_rate:0.02,safe_success_rate:0.02,d_min_uav:0.05,d_min_obs:0.05,d_c:0.1,speed:0.02,t_goal:0.5}
reproduce-table3: $(STAMP)
	@echo "make reproduce-table3: twelve rows from the shipped checkpoints, $(EPISODES) episodes per checkpoint, about $$(( ($(EPISODES) * 16 + 499) / 500 )) minutes (14-19 at 500 episodes on a 2-core machine)"
	$(PYTHON) scripts/reproduce.py table=3 episodes=$(EPISODES) $(R_ARG) 'compare_to=results/$${scenario.reading}/table3.csv' '++compare_tolerance=$(REPRODUCE_TOLERANCE)'

# reproduce-table4, reproduce-table5: Table IV or V.
reproduce-table%: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=$* episodes=$(EPISODES) $(R_ARG)

# Table III of the paper-recipe checkpoints (checkpoints/paper_fit/paper_recipe/).
reproduce-table3-paper: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=3 recipe=paper episodes=$(EPISODES) reading=paper_fit

figures: $(STAMP)
	$(PYTHON) scripts/figures.py $(R_ARG)

# The named step that updates results/ and figures/: every table and figure, the swarm-size tables and
# the claims, both readings (PUBLISH_READINGS=paper_fit: one of them, after only its checkpoints changed).
PUBLISH_READINGS ?= literal paper_fit
publish: $(STAMP)
	$(PUBLISH) publish "readings=$(PUBLISH_READINGS)" episodes=$(EPISODES) scaling.episodes=$(SCALING_EPISODES)

# Tables III-V, Figures 4-6 and the paper recipe's Table III of each reading (part of publish).
publish-tables: $(STAMP)
	$(PUBLISH) publish-tables "readings=$(PUBLISH_READINGS)" episodes=$(EPISODES)

# The paper's claims over the seeds of each published Table III (docs/specification.md section 10):
# results/<reading>/table3[_paper_recipe]_claims.md (with per-policy means and IQMs over seeds) and
# figures/<reading>/table3[_paper_recipe]_performance_profile.png, from the *_seeds.csv tables publish writes;
# results/<reading>/claims_overview.md (paper / fast / paper recipe per claim), quoted in README.md.
publish-claims: $(STAMP)
	$(PUBLISH) publish-claims

# The parts of publish that change when paper-recipe checkpoints are shipped, alone (paper_fit):
# the paper recipe's Table III, the fast Table III (its "Policy3-G (paper recipe)" row pools
# the shipped seeds), Fig. 4 with its convergence table, and the claims.
publish-paper-recipe: $(STAMP)
	$(PUBLISH) publish-paper-recipe episodes=$(EPISODES)

# The swarm-size tables (docs/specification.md section 7; docs/scaling.md): Policy3-G trained at 5 (its
# lowest shipped seed), the mixed-size Policy3-G (seed 0), every shipped seed of the scaling policy
# Policy3-G-crowd-ramp-allround-radial (experiment=mixed_cluttered) and the rule-based Policy-MA and
# Policy-OP, at N = 5-100, on the training scenario (results/<r>/scaling.*) and the forest
# (results/<r>/scaling_forest.*); a reading without the mixed checkpoints flies the rest. About an hour
# at 500 episodes for both scenarios of paper_fit on one core.
SCALING_READINGS ?= literal paper_fit
SCALING_EPISODES ?= 500
SCALING_SCENARIOS ?= train forest
publish-scaling: $(STAMP)
	$(PUBLISH) publish-scaling "scaling.readings=$(SCALING_READINGS)" scaling.episodes=$(SCALING_EPISODES) "scaling.scenarios=$(SCALING_SCENARIOS)"

tune-baselines: $(STAMP)
	$(PYTHON) scripts/tune_baselines.py $(R_ARG)

# Throughput ratios against baselines run in the same process (VmasEnv needs the bench extra);
# benchmarks/ is a tool of the repository, not of the installed package. ARGS: e.g. quick=true.
benchmark: $(STAMP)
	$(PYTHON) -m pip install --quiet -e ".[bench]"
	OMP_NUM_THREADS=1 $(PYTHON) -m benchmarks.run $(ARGS)

# The benchmark docs/throughput.md quotes: make benchmark (its command, the machine's fingerprint and
# load, the rows) into outputs/benchmark/, then published as results/benchmark.md with docs/throughput.md's
# copy of it. ARGS as benchmark's.
publish-benchmark: benchmark
	$(PUBLISH) publish-benchmark

# Policy3-G (trained with 5 UAVs), and the mixed-size one where shipped, flown by 5 to 100
# UAVs, into outputs/scaling/<reading>/.
scaling: $(STAMP)
	$(PUBLISH) scaling scaling_outputs.reading=$(READING)

# Three dimensions (docs/specification.md section 11; docs/threed.md). train-3d: Policy3-G and its no-instinct
# twin Policy2-G trained on train3d and wall3d's world (experiment=fast3d, 240k frames; SAC's target entropy
# -|A| = -3), five seeds each as a population (THREED_SEEDS), into runs/threed/, one at a time.
# train-3d-scaling: the flocks at scale in space (experiment=mixed_cluttered3d, three seeds as a population):
# Policy3-G-crowd-ramp-allround-radial and its twin with the paper's camera, into runs/, two at a time.
THREED_SEEDS ?= 5
THREED_EPISODES ?= 500
THREED_RUNS ?= runs/threed
train-3d: $(STAMP)
	$(SWEEP) hydra.launcher.n_jobs=1 experiment=fast3d scenario=train3d seed=0 population=$(THREED_SEEDS) policy=policy3_g,policy2_g reading=$(CHECK_READING) hydra.sweep.dir=$(THREED_RUNS)
train-3d-scaling: $(STAMP)
	$(SWEEP) experiment=mixed_cluttered3d scenario=train3d seed=0 population=3 compile=step policy=policy3_g_crowd_ramp_allround_radial,policy3_g_crowd_ramp_radial reading=$(CHECK_READING) hydra.sweep.dir=$(RUNS)

# ship-threed: the named step that updates checkpoints/<reading>/threed/ and mixed_cluttered3d/: the slim
# policies of the finished runs of train-3d (THREED_RUNS) and train-3d-scaling, <policy>/seed<k>.pt, each
# collection with its MANIFEST.md (conf/ship.yaml).
ship-threed: $(STAMP)
	$(PYTHON) scripts/ship.py reading=$(CHECK_READING) only=threed scenario_collections.threed.runs_dir=$(THREED_RUNS)
	$(PYTHON) scripts/ship.py reading=$(CHECK_READING) only=mixed_cluttered3d scenario_collections.mixed_cluttered3d.runs_dir=$(RUNS)

# table3-3d: the finished runs of train-3d, before they are shipped, and the two baselines on train3d, forest3d
# and wall3d, THREED_EPISODES episodes each, as publish-threed's table and figures, into outputs/threed/<reading>/.
table3-3d: $(STAMP)
	$(PUBLISH) table3-3d table3_3d.reading=$(CHECK_READING) "table3_3d.runs=$(THREED_RUNS)/fast3d/<reading>/*/seed*/last.pt" table3_3d.episodes=$(THREED_EPISODES)

# publish-threed: the named step that writes the 3-D results (docs/specification.md section 11) from
# checkpoints/<reading>/threed/ and mixed_cluttered3d/ (make ship-threed): every shipped seed of Policy3-G and
# Policy2-G and the baselines Policy-MA and Policy-OP on train3d, forest3d and wall3d, EPISODES each, with the
# verdicts, into results/<reading>/table3_3d.{md,csv} and table3_3d_seeds.csv; one episode of Policy-OP and of
# Policy3-G's seed of median success on each scenario as a GIF, and a frame on wall3d, figures/<reading>/threed_*
# (which seed: results/<reading>/threed_figures.md); Policy3-G's seeds, the flocks at scale and the baselines
# flown by 5-100 UAVs on train3d and forest3d, THREED_SCALING_EPISODES episodes per checkpoint and size,
# results/<reading>/scaling_{train3d,forest3d}.{md,csv,png}, and their pooled verdicts; the documents. The rows
# flown: conf/publish.yaml's threed.
THREED_SCALING_EPISODES ?= 500
publish-threed: $(STAMP)
	$(PUBLISH) publish-threed threed.reading=$(CHECK_READING) threed.episodes=$(EPISODES) threed.scaling_episodes=$(THREED_SCALING_EPISODES)

clean:
	rm -rf outputs multirun .pytest_cache
