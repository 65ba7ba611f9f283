# Two commands do everything:
#   make        create .venv, install pinned dependencies, reproduce every result
#   make test   create .venv if missing, install test tools, run the test suite
PYTHON ?= python3
VENV   := .venv
PY     := $(CURDIR)/$(VENV)/bin/python
RUNTIME_STAMP := $(VENV)/.runtime-installed
DEV_STAMP     := $(VENV)/.dev-installed
REPORT_STAMP  := $(VENV)/.report-installed

.PHONY: all problem1 problem2 studies beyond p2-baselines p2-main p2-studies p2-panel p2-map-pool \
	p2-stability p2-memory p2-memory-levers p2-memory-panel p2-one-step-unseen p2-one-step-levers \
	p2-memory-why p2-clock p2-beacon p2-beacon-long p2-beacon-long-study p2-evaluate p2-multiplicity report \
	test lint \
	bench clean

all: problem1 problem2 report

$(VENV)/bin/python:
	$(PYTHON) -m venv $(VENV)

$(RUNTIME_STAMP): requirements.txt | $(VENV)/bin/python
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	touch $@

$(DEV_STAMP): requirements-dev.txt $(RUNTIME_STAMP) $(REPORT_STAMP)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements-dev.txt
	touch $@

$(REPORT_STAMP): report/requirements.txt | $(VENV)/bin/python
	$(PY) -m pip install --quiet --disable-pip-version-check -r report/requirements.txt
	touch $@

## Problem 1: value iteration, Q-iteration, figures, stochasticity study (seconds).
problem1: $(RUNTIME_STAMP)
	cd problem1 && $(PY) train.py && $(PY) stochasticity_study.py

## Problem 2: the baselines and the evaluation of the committed models (the main experiment
## and the studies; `make studies` retrains them).
P2_STUDIES := results/studies
problem2: p2-baselines p2-evaluate p2-multiplicity

p2-baselines: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m analysis.baselines

## The main experiment: 3 modes x 10 seeds of 300 k env steps (about 4 min on 2 cores).
## It retrains on purpose, so its runs replace the earlier batch (--overwrite).
p2-main: $(RUNTIME_STAMP)
	cd problem2 && $(PY) train.py --overwrite

# Every mode and seed of the main experiment and of the studies found beside it: the report's
# analyses (analysis/pipeline.py), which write every file of evaluation_results/ (the three
# that `python evaluate.py` writes among them, in full).
p2-evaluate: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m analysis.pipeline

# Holm's correction over the panel's effects and over the interventions (seconds; reads the
# panel's and the evaluation's JSON, writes studies/panel/multiplicity.json).
p2-multiplicity: $(RUNTIME_STAMP) p2-evaluate
	cd problem2 && $(PY) -m studies.multiplicity

## The studies of the default task: the main experiment, the reward study (both rewards,
## 3 modes x 10 seeds, checkpoints chosen by the trained reward's own return, and the exact
## DP), messages without DIAL, then their evaluation, and the map panel (it evaluates itself).
studies: p2-main p2-studies p2-evaluate p2-panel p2-memory-panel

## Beyond the default task (measured times are in the README): agents on a pool of generated maps,
## the stability study, agents with memory (GRU, and one step) and the levers tried on them (each
## writes its own results; `make p2-evaluate` reads only the main experiment and `make studies`').
beyond: p2-map-pool p2-stability p2-memory p2-memory-levers p2-one-step-unseen p2-one-step-levers \
	p2-memory-why p2-clock p2-beacon p2-beacon-long p2-beacon-long-study

p2-studies: $(RUNTIME_STAMP)
	cd problem2 && for reward in per_step arrival; do \
		$(PY) train.py --reward_mode $$reward --target_potential 0 --select_by return --overwrite \
			--output_dir $(P2_STUDIES)/reward/$$reward || exit 1; done
	cd problem2 && $(PY) -m studies.reward_study
	cd problem2 && $(PY) train.py --mode comm,full --comm_learning none --num_seeds 3 \
		--overwrite --output_dir $(P2_STUDIES)/no_dial

## Where does information enable coordination? The map panel: the assignment's map (641) and
## the generator's map seeds 0-10 (studies/panel.py: PANEL_MAP_SEEDS), the main experiment's
## recipe, 4 modes (independent, comm, distance, full) x training seeds 641-645 on each map;
## then the panel's evaluation and the longer run on its hardest map (37 min on 2 cores).
PANEL_MAPS := 641 0 1 2 3 4 5 6 7 8 9 10
p2-panel: $(RUNTIME_STAMP)
	cd problem2 && for map in $(PANEL_MAPS); do \
		$(PY) train.py --mode independent,comm,distance,full --map_seed $$map --num_seeds 5 \
			--overwrite --output_dir $(P2_STUDIES)/panel/map$$map || exit 1; done
	cd problem2 && $(PY) -m studies.panel
	cd problem2 && $(PY) -m studies.panel_long

## Does one step of memory change what the channels are worth? The panel's 12 maps x 4 modes x
## training seeds 641-645 with one-step memory agents (studies/one_step), the main recipe, tested
## against the memoryless panel (about 40 min on 2 cores (estimated); reads the map panel).
p2-memory-panel: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.one_step.panel --train

## Agents trained on a pool of 2000 generated maps, tested on 40 held-out maps (about 5 min).
p2-map-pool: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.map_pool_study

## Does learning hold its peak? Five settings x 3 modes x training seeds 100-103, last weights
## (about 7 min).
p2-stability: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.stability_study --train

## Agents with memory (GRU) on the map pool: 4 modes x 5 seeds, tested on the held-out maps
## (31 min; reads the map-pool study's results).
p2-memory: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.memory.study

## Levers that might make a receiver listen (full mode, training seeds 100-101, validation maps;
## about 19 min).
p2-memory-levers: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.memory.levers

## One-step memory agents on the map pool, tested on the held-out maps; the levers on training seeds.
p2-one-step-unseen: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.one_step.unseen

p2-one-step-levers: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.one_step.unseen --levers

## Teaching the listener on maps never seen: the screen of the training options on training
## seeds (validation maps) in two stages, then its winner's 4 modes x seeds 0-4 on the held-out maps.
p2-beacon: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.one_step.beacon_screen
	cd problem2 && $(PY) -m studies.one_step.beacon_around
	cd problem2 && $(PY) -m studies.one_step.beacon_study

## The listener at two million steps: the screen's R + H + D cell (full) and its independent twin
## R + H, 2 M steps, training seeds 100-107, validation maps, with the pass rule for a held-out test.
p2-beacon-long: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.one_step.beacon_long

## Its held-out study (it refuses to run unless the pass rule held): the cell's 4 modes (full and
## independent on seeds 0-9, comm and distance on 0-4) and the recipe's independent agents at 2 M
## (seeds 0-4) on the 40 held-out maps; reads p2-beacon's beacon_around.json and beacon.json.
p2-beacon-long-study: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.one_step.beacon_long_study

## Why one step of memory is enough (reads the memory panel's agents; trains its ablations).
p2-memory-why: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.one_step.why --train

## A clock or any changing input? Memoryless agents whose distance is the step, or noise (trains both).
p2-clock: $(RUNTIME_STAMP)
	cd problem2 && $(PY) -m studies.one_step.clock --train

## The written report, report.pdf (at most 12 pages), and its companion report/studies.pdf (the
## studies in detail), both built from the result files (seconds). The cover's name and email are
## the README's "Full name" and "USC email" fields, read by every build; this fills them once:
##   make report NAME="Full Name" EMAIL="you@usc.edu"   (values given on this command line only)
REPORT_ARGS = $(if $(filter command line,$(origin NAME)),--name "$(NAME)") \
	$(if $(filter command line,$(origin EMAIL)),--email "$(EMAIL)")
report: $(REPORT_STAMP)
	$(PY) report/build.py $(REPORT_ARGS)

test: $(DEV_STAMP)
	$(PY) -m pytest

lint: $(DEV_STAMP)
	$(PY) -m ruff check problem1 problem2 tests bench report
	$(PY) -m ruff format --check problem1 problem2 tests bench report

bench: $(RUNTIME_STAMP)
	$(PY) bench/p1_scaling.py
	$(PY) bench/p2_env_throughput.py
	$(PY) bench/p2_update.py

clean:
	rm -rf $(VENV)
