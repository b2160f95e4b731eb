# Two commands on a fresh machine: `make demo` and `make test` (each sets up .venv first).
VENV ?= .venv
PY := $(VENV)/bin/python
BIN := $(VENV)/bin
DEMO := runs/demo

.PHONY: setup demo test format bench publish ship results-doc results-orca records report generalization

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet -e ".[dev,onnx,ros,ray]"
	# pyrvo (the RVO2 reference for the ORCA oracle test) declares a large dependency it does not use.
	$(PY) -m pip install --quiet --no-deps pyrvo==0.4.3
	touch $@

demo: setup
	$(BIN)/crowdplan eval --model lsa-dsac --default-world --episodes 500 --out $(DEMO)/lsa-dsac-circle --force
	$(BIN)/crowdplan render --model lsa-dsac --default-world --case 0 --out $(DEMO)/lsa-dsac-case0.gif --force

test: setup
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(PY) -m pytest

format: setup
	$(BIN)/ruff format src tests benchmarks
	$(BIN)/ruff check --fix src tests benchmarks

bench: setup
	$(PY) benchmarks/bench_sim.py
	$(PY) benchmarks/bench_update.py

# Copy the small artefacts of a training run into results/ (for a DSAC run with a checkpoint also
# its last networks, which dsac.init_networks can start another run from) and test its best
# model on the 500 circle_crossing and the 500 square_crossing (transfer) test cases:
#   make publish RUN=runs/lsa_dsac-s0
# EVAL_ARGS go to both evaluations, e.g. EVAL_ARGS="--humans 5" for CADRL, which trains with one
# human and is tested, as in the paper, with five.
EVAL_ARGS ?=
publish: setup
	@test -n "$(RUN)" || (echo "usage: make publish RUN=runs/<run>"; exit 2)
	mkdir -p results/train/$(notdir $(RUN))
	cp $(addprefix $(RUN)/,config.yaml meta.json episodes.csv validation.csv updates.csv curves.png best_model.pt) results/train/$(notdir $(RUN))/
	if grep -q '"algo": "dsac"' $(RUN)/meta.json && test -f $(RUN)/checkpoint.pt; then $(PY) -m crowdplan.algos.dsac_networks $(RUN)/checkpoint.pt results/train/$(notdir $(RUN))/networks.pt; fi
	$(BIN)/crowdplan eval --model $(RUN)/best_model.pt --episodes 500 $(EVAL_ARGS) --out results/train/$(notdir $(RUN))/test --force
	$(BIN)/crowdplan eval --model $(RUN)/best_model.pt --episodes 500 --scenario square_crossing $(EVAL_ARGS) --out results/train/$(notdir $(RUN))/test-square --force

# Make a published run's best-validation model the shipped model NAME (default lsa-dsac), with
# a safety shield of SHIELD seconds if given (docs/generalization.md):
#   make ship RUN=results/train/<run> [NAME=lstm-a2c] [SHIELD=2.5]
NAME ?= lsa-dsac
ship:
	@test -f "$(RUN)/best_model.pt" || (echo "usage: make ship RUN=results/train/<run> [NAME=<model>] [SHIELD=<seconds>]"; exit 2)
	mkdir -p models/$(NAME)
	cp $(RUN)/best_model.pt models/$(NAME)/model.pt
	cp $(RUN)/config.yaml models/$(NAME)/config.yaml
	$(if $(SHIELD),$(PY) -m crowdplan.planner_options models/$(NAME)/model.pt --shield $(SHIELD))

# Regenerate every table of docs/results.md and docs/training.md from the committed result folders.
results-doc: setup
	$(BIN)/crowdplan report --fill docs/results.md
	$(BIN)/crowdplan report --fill docs/training.md

# Trajectory records (crowdplan eval --record) of the 500 test cases that the report's strategy and
# attention analyses read: shipped models, ORCA, the blind baseline and two encoder runs on
# circle_crossing; the paper-faithful model and ORCA also on square_crossing.
RECORD_CIRCLE := --model=lsa-dsac --model=lsa-dsac-paper --model=lsa-dsac-paper-goal \
	--model=lstm-a2c --policy=orca --policy=straight \
	--model=results/train/rg_dsac_ent05-s0 --model=results/train/sa_dsac_ent05-s0
RECORD_SQUARE := --model=lsa-dsac --model=lsa-dsac-paper --policy=orca
records: setup
	for p in $(RECORD_CIRCLE); do $(BIN)/crowdplan eval $$p --default-world --episodes 500 --record --force -q \
		--out results/records/circle/$$(basename $${p#*=}) > /dev/null || exit 1; done
	for p in $(RECORD_SQUARE); do $(BIN)/crowdplan eval $$p --default-world --episodes 500 --record --force -q \
		--scenario square_crossing --out results/records/square/$$(basename $${p#*=}) > /dev/null || exit 1; done

# Every shipped planner in every generalisation test world (docs/generalization.md).
PLANNERS := lsa-dsac lsa-dsac@shield=0 lsa-dsac-paper lsa-dsac-paper-goal lsa-dsac-unicycle \
	cadrl lstm-rl sarl lstm-a2c rg-dqn orca straight
generalization: setup
	$(PY) -m crowdplan.analysis.test_worlds --out results/generalization $(PLANNERS)
	$(BIN)/crowdplan report --fill docs/generalization.md

# The evaluation report (docs/report.md): an HTML page with every table and figure, from the
# committed result folders; then the tables of docs/results.md.
report: setup
	$(BIN)/crowdplan report --out docs/report
	$(BIN)/crowdplan report --fill docs/results.md

results-orca: setup
	$(BIN)/crowdplan eval --policy orca --scenario circle_crossing --episodes 500 --out results/orca/circle_crossing --force
	$(BIN)/crowdplan eval --policy orca --scenario square_crossing --episodes 500 --out results/orca/square_crossing --force
