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

.PHONY: install test test-all demo readme-demo docs train train-all check-train-all train-paper train-paper-all train-paper-populations train-fast-populations train-mixed ship-checkpoints \
        reproduce-table3 reproduce-table4 reproduce-table5 reproduce-table3-paper figures publish publish-tables publish-paper-recipe \
        publish-scaling publish-claims tune-baselines \
        benchmark publish-benchmark scaling train-3d ship-threed table3-3d publish-threed clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(PYTHON) -m pip install --quiet --upgrade pip
	$(PYTHON) -m pip install --quiet "$(TORCH)"
	$(PYTHON) -m pip install --quiet -e ".[test]"
	touch $(STAMP)

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
# machine's name in docs/demo.md, and splice them into README.md.
DEMO_DIR := outputs/readme_demo
readme-demo: $(STAMP)
	rm -rf $(DEMO_DIR) && mkdir -p $(DEMO_DIR)
	$(PYTHON) scripts/train.py experiment=demo progress=false hydra.run.dir=$(DEMO_DIR)/run > $(DEMO_DIR)/demo.log \
		|| { cat $(DEMO_DIR)/demo.log; exit 1; }
	cat $(DEMO_DIR)/demo.log
	$(PYTHON) -m flock_torchrl.report.splice --demo $(DEMO_DIR)/demo.log $(DEMO_DIR)/run docs/demo.md
	$(PYTHON) -m flock_torchrl.report.splice README.md

# The documents' copies of results/ (docs/results.md's spliced blocks, README's "Where it stands"
# written from results/ into results/standing.md), refreshed from results/; the publish targets run it last.
docs: $(STAMP)
	$(PYTHON) -m flock_torchrl.report.standing results results/standing.md
	$(PYTHON) -m flock_torchrl.report.splice docs/results.md README.md
	$(PYTHON) -m flock_torchrl.report.splice docs/scaling.md docs/scaling_tables.md
	$(PYTHON) -m flock_torchrl.report.splice docs/threed.md

train: $(STAMP)
	$(PYTHON) scripts/train.py $(R_ARG) $(ARGS)

# The ten learned policies, three seeds each, experiment=fast, two single-threaded runs at a
# time (Hydra's joblib launcher), into $(RUNS)/fast/<reading>/; a killed sweep continues where it
# stopped (resume=auto). Eager: at B = 32 the compiled step recompiles for each policy's world
# (10-25 s each), more than it saves; the compiled loss does not pay at minibatch 1280.
LEARNED := policy1,policy1_g,policy2,policy2_g,policy3,policy3_g,policy4_g,policy5_g,policyd_g,policyp_g
SEEDS   ?= 0,1,2
RUNS    ?= runs
train-all: $(STAMP)
	OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py -m hydra/launcher=local experiment=fast progress=false \
		resume=auto seed=$(SEEDS) policy=$(LEARNED) hydra.sweep.dir=$(RUNS) $(R_ARG) $(ARGS)

# `make train-all` timed from nothing into outputs/train_all/<reading>/ (runs/, then its shipped
# policies in checkpoints/), then its Table III (500 episodes per seed) written there beside the
# shipped one, results/<reading>/table3.csv: table3_vs_reference.md says, per policy, whether
# success stays within 1 point and d_min_uav within 0.1 m. Refuses a folder that exists.
CHECK_READING := $(or $(READING),paper_fit)
CHECK   ?= outputs/train_all/$(CHECK_READING)
ROWS    ?= Policy1,Policy1-G,Policy2,Policy2-G,Policy3,Policy3-G,Policy4-G,Policy5-G,PolicyD-G,PolicyP-G
check-train-all: $(STAMP)
	@test ! -e $(CHECK) || { echo "error: $(CHECK) exists; move it away for a timing from nothing" >&2; exit 2; }
	start=$$(date +%s); \
	$(MAKE) --no-print-directory train-all RUNS=$(CHECK)/runs READING=$(CHECK_READING) || exit 1; \
	echo "make train-all READING=$(CHECK_READING) SEEDS=$(SEEDS): $$(( $$(date +%s) - start )) s wall" | tee $(CHECK)/wall.txt
	$(PYTHON) scripts/ship.py reading=$(CHECK_READING) runs_dir=$(CHECK)/runs checkpoints_dir=$(CHECK)/checkpoints
	$(PYTHON) scripts/reproduce.py table=3 episodes=$(EPISODES) reading=$(CHECK_READING) \
		checkpoints_dir=$(CHECK)/checkpoints only=[$(ROWS)] \
		compare_to=results/$(CHECK_READING)/table3.csv hydra.run.dir=$(CHECK)/table3

# The paper's own recipe (Table I, one env, one update per step, 5000 episodes) for Policy3-G.
train-paper: $(STAMP)
	OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py experiment=paper policy=policy3_g seed=0 progress=false compile=true \
		resume=auto $(R_ARG)

# The paper's recipe for the policies Table III's claims rest on, under paper_fit:
# seed 0 of seven policies (Policy3-G's seed 0 is `make train-paper`), then seeds 1 and 2 of
# Policy3-G, 4-G and 5-G; two single-threaded runs at a time (about 3.5 hours each here), each
# resuming where it stopped and a finished one doing nothing (resume=auto).
PAPER_RUNS := policy1:0 policy1_g:0 policy2:0 policy2_g:0 policy3:0 policy4_g:0 policy5_g:0 \
              policy3_g:1 policy4_g:1 policy5_g:1 policy3_g:2 policy4_g:2 policy5_g:2
train-paper-all: $(STAMP)
	printf '%s\n' $(PAPER_RUNS) | tr ':' ' ' | xargs -P 2 -n 2 sh -c 'OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py \
		experiment=paper policy=$$0 seed=$$1 reading=paper_fit progress=false compile=true resume=auto'

# Ten seeds of a policy as one population (docs/population.md): seeds 0-9 of the eight policies the
# paper's claims rest on, under the paper's recipe (paper_fit), two populations at a time, each
# resuming where it stopped (resume=auto); then the nine off-policy learners under `fast`.
# PolicyP-G (PPO) trains no population: its ten fast seeds are `make train-all SEEDS=0,...,9 LEARNED=policyp_g`.
POPULATION ?= 10
PAPER_POPULATIONS := policy3_g policy3 policy1_g policy1 policy2_g policy2 policy4_g policy5_g
FAST_POPULATIONS  := policy1 policy1_g policy2 policy2_g policy3 policy3_g policy4_g policy5_g policyd_g
train-paper-populations: $(STAMP)
	printf '%s\n' $(PAPER_POPULATIONS) | xargs -P 2 -I{} sh -c 'OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py \
		experiment=paper policy={} seed=0 population=$(POPULATION) reading=paper_fit progress=false resume=auto'

# POP_SEED: the first member's seed (literal's shipped seeds 3-9: POPULATION=7 POP_SEED=3).
POP_SEED ?= 0
train-fast-populations: $(STAMP)
	printf '%s\n' $(FAST_POPULATIONS) | xargs -P 2 -I{} sh -c 'OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py \
		experiment=fast policy={} seed=$(POP_SEED) population=$(POPULATION) progress=false resume=auto $(R_ARG)'

# One Policy3-G trained on 5, 20 and 50 UAVs at once (experiment=mixed), three seeds, two at a time.
train-mixed: $(STAMP)
	OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py -m hydra/launcher=local experiment=mixed policy=policy3_g \
		progress=false resume=auto seed=$(SEEDS) $(R_ARG)

# The named step that updates checkpoints/ (slim policies of the finished runs, per reading).
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
	@echo "make reproduce-table3: twelve rows from the shipped checkpoints, $(EPISODES) episodes per checkpoint," \
		"about $$(( ($(EPISODES) * 16 + 499) / 500 )) minutes (14-19 at 500 episodes on a 2-core machine)"
	$(PYTHON) scripts/reproduce.py table=3 episodes=$(EPISODES) $(R_ARG) \
		'compare_to=results/$${scenario.reading}/table3.csv' '++compare_tolerance=$(REPRODUCE_TOLERANCE)'

reproduce-table4: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=4 episodes=$(EPISODES) $(R_ARG)

reproduce-table5: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=5 episodes=$(EPISODES) $(R_ARG)

# Table III of the paper-recipe checkpoints (checkpoints/paper_fit/paper_recipe/).
reproduce-table3-paper: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=3 recipe=paper episodes=$(EPISODES) reading=paper_fit

figures: $(STAMP)
	$(PYTHON) scripts/figures.py $(R_ARG)

# The named step that updates results/ and figures/: every table and figure, both readings
# (PUBLISH_READINGS=paper_fit: one of them, after only its checkpoints changed).
PUBLISH_READINGS ?= literal paper_fit
publish: $(STAMP)
	$(MAKE) --no-print-directory publish-tables PUBLISH_READINGS="$(PUBLISH_READINGS)"
	$(MAKE) --no-print-directory publish-scaling SCALING_READINGS="$(PUBLISH_READINGS)"
	$(MAKE) --no-print-directory publish-claims
	$(MAKE) --no-print-directory docs

# Tables III-V, Figures 4-6 and the paper recipe's Table III of each reading (part of publish).
publish-tables: $(STAMP)
	for r in $(PUBLISH_READINGS); do \
		for t in 3 4 5; do \
			$(PYTHON) scripts/reproduce.py table=$$t episodes=$(EPISODES) reading=$$r hydra.run.dir=results/$$r || exit 1; \
		done; \
		$(PYTHON) scripts/figures.py reading=$$r hydra.run.dir=figures/$$r || exit 1; \
		if [ -n "$$(ls checkpoints/$$r/paper_recipe/*/seed*.pt 2>/dev/null)" ]; then \
			$(PYTHON) scripts/reproduce.py table=3 recipe=paper episodes=$(EPISODES) reading=$$r \
				hydra.run.dir=results/$$r || exit 1; \
		fi; \
	done

# The paper's claims over the seeds of each published Table III (docs/specification.md section 10):
# results/<reading>/table3[_paper_recipe]_claims.md (with per-policy means and IQMs over seeds) and
# figures/<reading>/table3[_paper_recipe]_performance_profile.png, from the *_seeds.csv tables publish writes;
# results/<reading>/claims_overview.md (paper / fast / paper recipe per claim), quoted in README.md.
publish-claims: $(STAMP)
	for f in results/*/table3_seeds.csv results/*/table3_paper_recipe_seeds.csv; do \
		test -f $$f || continue; \
		r=$$(basename $$(dirname $$f)); t=$$(basename $${f%_seeds.csv}); \
		$(PYTHON) -m flock_torchrl.report.seeds $$f $${f%_seeds.csv}_claims.md \
			figures/$$r/$${t}_performance_profile.png || exit 1; \
	done
	for r in literal paper_fit; do \
		$(PYTHON) -m flock_torchrl.report.seeds --overview results/$$r/claims_overview.md \
			"fast recipe=results/$$r/table3_seeds.csv" "paper recipe=results/$$r/table3_paper_recipe_seeds.csv" || exit 1; \
	done
	$(MAKE) --no-print-directory docs

# The parts of publish that change when paper-recipe checkpoints are shipped, alone (paper_fit):
# the paper recipe's Table III, the fast Table III (its "Policy3-G (paper recipe)" row pools
# the shipped seeds), and Fig. 4 with its convergence table.
publish-paper-recipe: $(STAMP)
	$(PYTHON) scripts/reproduce.py table=3 episodes=$(EPISODES) reading=paper_fit hydra.run.dir=results/paper_fit
	$(PYTHON) scripts/reproduce.py table=3 recipe=paper episodes=$(EPISODES) reading=paper_fit \
		hydra.run.dir=results/paper_fit
	$(PYTHON) scripts/figures.py reading=paper_fit figs=[4] hydra.run.dir=figures/paper_fit
	$(MAKE) --no-print-directory publish-claims
	$(MAKE) --no-print-directory docs

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
	for r in $(SCALING_READINGS); do \
		others=$$(ls checkpoints/$$r/mixed/policy3_g/seed0.pt \
			checkpoints/$$r/mixed_cluttered/policy3_g_crowd_ramp_allround_radial/seed*.pt \
			2>/dev/null | paste -sd, -); \
		for s in $(SCALING_SCENARIOS); do \
			$(PYTHON) scripts/scaling.py reading=$$r scenario=$$s episodes=$(SCALING_EPISODES) \
				hydra.run.dir=results/$$r "others=[$${others}$${others:+,}policy_ma,policy_op]" || exit 1; \
		done; \
	done
	$(MAKE) --no-print-directory docs

tune-baselines: $(STAMP)
	$(PYTHON) scripts/tune_baselines.py $(R_ARG)

# Throughput ratios against baselines run in the same process (VmasEnv needs the bench extra);
# benchmarks/ is a tool of the repository, not of the installed package. ARGS: e.g. quick=true.
# Three dimensions (docs/specification.md section 11). train-3d: Policy3-G and its no-instinct twin
# Policy2-G trained on train3d (experiment=fast; SAC's target entropy -|A| = -3 by default), seeds
# THREED_SEEDS (the five shipped), into runs/threed/ (3-7 min a run on one core here, two at a time). Runs trained while this target
# passed algo.target_entropy=-3.0 (the same value) are named seed<k>__algo.target_entropy--3.0__scenario-train3d;
# ship-threed ships those too, but a new train-3d trains its own seed<k>__scenario-train3d beside them.
# table3-3d: each of those seeds and the two baselines on train3d, forest3d and wall3d,
# THREED_EPISODES episodes each (scripts/evaluate.py), into outputs/threed/<reading>/, then their
# table in the form of Table III, outputs/threed/<reading>/table3_3d.md, and one seeded episode of
# Policy-OP and of Policy3-G's first seed on each as a GIF of a top and a side view (flock_torchrl/report/threed.py).
THREED_SEEDS ?= 0,1,2,3,4
THREED_EPISODES ?= 500
THREED_RUNS ?= runs/threed
THREED_OUT ?= outputs/threed/$(CHECK_READING)
THREED_SCENARIOS := train3d forest3d wall3d
train-3d: $(STAMP)
	OMP_NUM_THREADS=1 $(PYTHON) scripts/train.py -m hydra/launcher=local experiment=fast scenario=train3d \
		progress=false resume=auto seed=$(THREED_SEEDS) policy=policy3_g,policy2_g \
		reading=$(CHECK_READING) hydra.sweep.dir=$(THREED_RUNS)

# ship-threed: the named step that updates checkpoints/<reading>/threed/: the slim policies of the
# finished runs of train-3d (THREED_RUNS), <policy>/seed<k>.pt, with their MANIFEST.md (conf/ship.yaml).
ship-threed: $(STAMP)
	$(PYTHON) scripts/ship.py reading=$(CHECK_READING) only=threed scenario_collections.threed.runs_dir=$(THREED_RUNS)

table3-3d: $(STAMP)
	set -e; for ckpt in $(THREED_RUNS)/fast/$(CHECK_READING)/*/seed*/last.pt; do \
		pol=$$(basename $$(dirname $$(dirname $$ckpt))); seed=$$(basename $$(dirname $$ckpt) | cut -d_ -f1); \
		for sc in $(THREED_SCENARIOS); do OMP_NUM_THREADS=1 $(PYTHON) scripts/evaluate.py checkpoint=$$ckpt \
			scenario=$$sc episodes=$(THREED_EPISODES) hydra.run.dir=$(THREED_OUT)/$$pol/$$seed/$$sc; done; done
	set -e; for pol in policy_ma policy_op; do for sc in $(THREED_SCENARIOS); do OMP_NUM_THREADS=1 $(PYTHON) \
		scripts/evaluate.py policy=$$pol scenario=$$sc episodes=$(THREED_EPISODES) reading=$(CHECK_READING) \
		hydra.run.dir=$(THREED_OUT)/$$pol/rule/$$sc; done; done
	$(PYTHON) -c "from flock_torchrl.report.threed import write_table; print(open(write_table('$(THREED_OUT)')).read())"
	$(PYTHON) -c "import glob; from flock_torchrl.report.threed import episode_gifs; \
		seeds = sorted(glob.glob('$(THREED_RUNS)/fast/$(CHECK_READING)/policy3_g/seed*/last.pt'))[:1]; \
		[print(p) for x in ['policy_op', *seeds] for p in episode_gifs('$(THREED_OUT)', x, reading='$(CHECK_READING)')]"

# publish-threed: the named step that writes the 3-D results (docs/specification.md section 11) from
# checkpoints/<reading>/threed/ (make ship-threed): every shipped seed of Policy3-G and Policy2-G and the
# baselines Policy-MA and Policy-OP on train3d, forest3d and wall3d, EPISODES each, with the verdicts, into
# results/<reading>/table3_3d.{md,csv} and table3_3d_seeds.csv; one episode of Policy-OP and of Policy3-G's
# first seed on each as a GIF and a frame on wall3d, figures/<reading>/threed_*; Policy3-G's seeds and the
# baselines flown by 5-100 UAVs on train3d, THREED_SCALING_EPISODES episodes per size,
# results/<reading>/scaling_train3d.{md,csv,png}; then make docs. 929 s on one core here (paper_fit, five seeds
# each, 500 episodes per seed and scenario, 200 per swarm size: about 6 min of table and figures, 10 of scaling).
THREED_SCALING_EPISODES ?= 200
publish-threed: $(STAMP)
	set -e; r=$(CHECK_READING); \
	test -n "$$(ls checkpoints/$$r/threed/policy3_g/seed*.pt 2>/dev/null)" || \
		{ echo "error: no checkpoints/$$r/threed/policy3_g/seed*.pt (make ship-threed)" >&2; exit 2; }; \
	OMP_NUM_THREADS=1 $(PYTHON) -m flock_torchrl.report.threed results/$$r figures/$$r $$r $(EPISODES) \
		checkpoints/$$r/threed/policy3_g/seed*.pt $$(ls checkpoints/$$r/threed/policy2_g/seed*.pt 2>/dev/null); \
	OMP_NUM_THREADS=1 $(PYTHON) scripts/scaling.py reading=$$r scenario=train3d episodes=$(THREED_SCALING_EPISODES) \
		sizes=[5,10,20,50,100] policy_name=policy_ma hydra.run.dir=results/$$r \
		"others=[$$(ls checkpoints/$$r/threed/policy3_g/seed*.pt | paste -sd, -),policy_op]"
	$(MAKE) --no-print-directory docs

benchmark: $(STAMP)
	$(PYTHON) -m pip install --quiet -e ".[bench]"
	OMP_NUM_THREADS=1 $(PYTHON) -m benchmarks.run $(ARGS)

# The benchmark docs/throughput.md quotes: make benchmark into results/benchmark.md (its command, the
# machine's fingerprint and load, the rows), then spliced into docs/throughput.md. ARGS as benchmark's.
publish-benchmark: $(STAMP)
	$(PYTHON) -m pip install --quiet -e ".[bench]"
	OMP_NUM_THREADS=1 $(PYTHON) -m benchmarks.run $(ARGS) hydra.run.dir=results
	$(PYTHON) -m flock_torchrl.report.splice docs/throughput.md

# Policy3-G (trained with 5 UAVs), and the mixed-size one where shipped, flown by 5 to 100
# UAVs, into outputs/scaling/<reading>/.
scaling: $(STAMP)
	r=$$($(PYTHON) -c "from flock_torchrl.config import compose; print(compose('scaling', [x for x in ['$(R_ARG)'] if x]).scenario.reading)"); \
	mixed=checkpoints/$$r/mixed/policy3_g/seed0.pt; \
	$(PYTHON) scripts/scaling.py $(R_ARG) $$(test -f $$mixed && echo "others=[$$mixed]")

clean:
	rm -rf outputs multirun .pytest_cache
