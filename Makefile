# Every target installs what it needs: on a fresh machine `make run` and
# `make test` are the whole set-up. `make run` installs only what running needs
# (torch, SUMO and this package); the extras come with the targets that use them.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev
PIP_FLAGS := --disable-pip-version-check -q -c constraints.txt
SEED ?= 0
WORKERS ?= 1

.PHONY: setup run test test-fast typecheck lint bench bench-scale soak learn-check pretrained traffic-policy paper realism own-nets dense flow ablation people styled-policy styles ramp clean

setup: $(DEV_STAMP)

# what running needs: the package without extras
$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install $(PIP_FLAGS) --upgrade pip
	$(BIN)/pip install $(PIP_FLAGS) torch==2.13.0
	$(BIN)/pip uninstall -y -q behave 2>/dev/null || true  # the distribution's former name
	$(BIN)/pip install $(PIP_FLAGS) -e .
	touch $(STAMP)

# what the tests, the type check and the linter use: pytest, ruff, mypy, the RL integrations, Ray,
# and the ffmpeg the MP4 test needs
$(DEV_STAMP): $(STAMP)
	$(BIN)/pip install $(PIP_FLAGS) -e '.[dev,integrations,distributed,video]'
	touch $(DEV_STAMP)

run: $(STAMP)
	$(BIN)/behave populate --seed $(SEED) --keep-count --fcd runs/populate/fcd.xml --plot runs/populate/traces.png
	$(BIN)/behave report runs/populate/fcd.xml --net sumo_scenarios/data/highway/highway.net.xml --out runs/populate

test: $(DEV_STAMP)
	$(BIN)/python -m pytest

# the tests that start no SUMO and train nothing (markers in pyproject.toml): about a minute
test-fast: $(DEV_STAMP)
	$(BIN)/python -m pytest -m "not sumo and not train"

typecheck: $(DEV_STAMP)
	$(BIN)/mypy

lint: $(DEV_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: $(STAMP)
	$(BIN)/pip install $(PIP_FLAGS) -e '.[bench]'
	$(BIN)/python benchmarks/bench_env.py
	$(BIN)/python benchmarks/bench_populate.py
	$(BIN)/python benchmarks/bench_connect.py

# bench_populate's rows at scale: under load, N populates at once, 10,000 agents (tens of minutes)
bench-scale: $(STAMP)
	mkdir -p runs/bench_scale
	$(BIN)/python benchmarks/bench_populate.py --rows 1000:200 --beside-cpu-burner --csv runs/bench_scale/burner.csv
	$(BIN)/python benchmarks/bench_populate.py --rows 1000:200 --parallel --csv runs/bench_scale/parallel.csv
	$(BIN)/python benchmarks/bench_populate.py --rows 10000:2000 --length 300000 --rounds 2 --memory \
		--csv runs/bench_scale/scale.csv

soak: $(STAMP)
	$(BIN)/python benchmarks/soak.py --jobs 2

learn-check: $(STAMP)
	$(if $(filter-out 1,$(WORKERS)),$(BIN)/pip install $(PIP_FLAGS) -e '.[distributed]')
	$(BIN)/python benchmarks/learn_check.py --seed $(SEED) --workers $(WORKERS)

pretrained: $(STAMP)
	$(BIN)/python benchmarks/make_pretrained.py --seed $(SEED)

traffic-policy: $(STAMP)
	$(BIN)/python benchmarks/make_pretrained.py --stages traffic

# the styled driver's policy: the teacher's demonstrations in pieces of 10 episodes, then the fit
STYLED_SEEDS ?= 1 2 3 4 5 6 7 21 22 23
styled-policy: $(STAMP)
	for s in $(STYLED_SEEDS); do $(BIN)/python benchmarks/make_styled.py --episodes 10 --seed $$s --collect-only || exit 1; done
	$(BIN)/python benchmarks/make_styled.py --fit-only $(foreach s,$(STYLED_SEEDS),--demos runs/styled/demos_seed$(s).npz)

# does each styled agent drive as its style asks (writes docs/styles.md)
styles: $(STAMP)
	$(BIN)/python benchmarks/style_response.py

realism: $(STAMP)
	$(BIN)/python benchmarks/traffic_bars.py --seeds 0,1,2 --duration 600

own-nets: $(STAMP)
	$(BIN)/python benchmarks/own_nets_bars.py --seeds 0,1

dense: $(STAMP)
	$(BIN)/python benchmarks/dense_bars.py --seed $(SEED)

flow: $(STAMP)
	$(BIN)/python benchmarks/flow.py --seed $(SEED) --jobs 2

# who drives: the shipped policy against its own median action held constant and against
# --driver rules, light and dense highway, seeds 0-2 (about 20 min of one core); writes docs/ablation.md
ablation: $(STAMP)
	$(BIN)/python benchmarks/ablation.py --seeds 0,1,2 --duration 1800
	$(BIN)/python benchmarks/ablation.py --seeds 0,1,2 --duration 900 --policy behaviors/pretrained/styled.pt \
		--doc docs/ablation-styled.md --out runs/ablation-styled

# like people: a highD-like 2-lane Autobahn at 130 km/h with a fifth lorries, SUMO alone and every
# car learned (traffic.pt; styled.pt with its default and its highd population; and with the lorries learned
# too), closest headways, lane changes, mean speeds and lane keeping through a 420 m window against highD's
# published figures, seeds 0-2 (about ten minutes); docs/people.md
people: $(STAMP)
	$(BIN)/python benchmarks/people.py --seeds 0,1,2 --duration 900

paper: $(STAMP)
	$(BIN)/python benchmarks/paper.py --seed $(SEED)

# lane drops, ramps and long vehicles: a user's 3-lane motorway with an on-ramp and a work zone
# (cars, lorries, vans) at shares 0-1 and a 3-lane one with lorries and coaches, seeds 0-1, collisions and
# who stood 30 s (about 20 min of one core); writes its section of docs/ramp.md
ramp: $(STAMP)
	$(BIN)/python benchmarks/ramp_bars.py --seeds 0,1 --jobs 2

clean:
	rm -rf $(VENV) runs build *.egg-info
