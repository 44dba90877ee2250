# Everything runs inside .venv, created on first use and reused after. Two stamps track pyproject
# changes: the runtime tier (what `make serve` needs: no torch) and the training and development
# tiers on top of it (what `make test`, `make train` and the scripts need).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
RUNTIME := $(VENV)/.runtime-installed
STAMP := $(VENV)/.installed
HOST ?= 127.0.0.1
PORT ?= 8000
URL ?= http://127.0.0.1:8000
DURATION ?= 60
MODEL ?= models/frt_unicycle.onnx
# make calibrate: recorded tracks (docs/coverage.md: the Argoverse 2 scenario, or the CSV format),
# the coverage of C to reach, and the name of the settings profile written (FRT_PROFILE=<name>).
DATA ?= data/av2/scenario_0a1e6f0a-1817-4a98-b02e-db8c9327d151.parquet
TARGET ?= 0.99
PROFILE ?= av2
FIND_LINKS := $(if $(wildcard /opt/wheels),--find-links /opt/wheels,)

.PHONY: venv serve demo viewer-screenshot test lint format train train-smoke evaluate evaluate-full compare-authors network-diagnostics bench bench-batch bench-scene bench-sustained bench-audit adapter-error load load-scale profile-load scale-test scenarios calibrate rescue plots clean

$(RUNTIME): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet $(FIND_LINKS) -e .
	touch $(RUNTIME)

$(STAMP): $(RUNTIME) pyproject.toml client/pyproject.toml
	$(BIN)/python -m pip install --quiet $(FIND_LINKS) -e '.[train,dev]' -e ./client
	touch $(STAMP)

venv: $(STAMP)

serve: $(RUNTIME)
	FRT_MODEL_PATH=$(MODEL) $(BIN)/uvicorn service.api.app:app --host $(HOST) --port $(PORT)

# The service on 127.0.0.1 and the Argoverse 2 scenario replayed into it at real time, looping;
# open the printed viewer URL. Ctrl-C stops both.
demo: $(STAMP)
	$(BIN)/python scripts/demo.py --host $(HOST) --port $(PORT) --model $(MODEL)

# docs/viewer.png: the viewer during the demo's replay, as headless Chromium shows it.
viewer-screenshot: $(STAMP)
	$(BIN)/python scripts/demo.py --port $(PORT) --model $(MODEL) --screenshot docs/viewer.png

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

test: lint
	$(BIN)/python -m pytest -q

# Reproduces the shipped model: train, export (contract graph + float32 twin), calibrate delta,
# distil the (x, y) projection network, then measure the accuracy written into the card.
train: $(STAMP)
	$(BIN)/python -m models.train --config models/configs/full.json --out runs/frt_unicycle
	cp runs/frt_unicycle/log.csv models/training_log.csv
	cp runs/frt_unicycle/train_meta.json models/training_meta.json
	$(BIN)/python -m models.export --run runs/frt_unicycle --out models
	$(BIN)/python -m models.evaluate --model $(MODEL) --calibrate --calibrate-only --write-card
	$(BIN)/python -m models.projection --model $(MODEL)
	$(BIN)/python -m models.projection --model $(MODEL) --calibrate-only
	$(MAKE) evaluate-full

train-smoke: $(STAMP)
	$(BIN)/python -m models.pipeline --config models/configs/smoke.json --out /tmp/frt-smoke

evaluate: $(STAMP)
	$(BIN)/python -m models.evaluate --model $(MODEL) --rollouts 65536

evaluate-full: $(STAMP)
	$(BIN)/python -m models.evaluate --model $(MODEL) --rollouts 65536 --write-card \
		--plot docs/frt_contours.png --json results/model_eval.json
	$(BIN)/python scripts/plot_training.py models/training_log.csv --out docs/training_loss.png
	$(BIN)/python scripts/model_report.py

# The paper authors' network (../shared/anchors, reference only) on the same rollouts as ours.
compare-authors: $(STAMP)
	$(BIN)/python scripts/compare_authors.py

# Does the network separate reachable from unreachable positions inside the outer bound?
network-diagnostics: $(STAMP)
	$(BIN)/python scripts/network_diagnostics.py --model $(MODEL)

bench: $(STAMP)
	$(BIN)/python scripts/bench.py --model $(MODEL)
	$(BIN)/python scripts/bench_batch.py --model $(MODEL)

# One batch of 500 candidate trajectories x 30 points against 10 agents, beside the same candidates
# checked one by one (results/bench_batch.json).
bench-batch: $(STAMP)
	$(BIN)/python scripts/bench_batch.py --model $(MODEL)

# A whole scene on one event loop, in-process: frames of 100 agents and two planners' checks of
# all of them at 10 Hz; how long a check waits behind frames (BASELINE=REV: that tree too).
bench-scene: $(STAMP)
	$(BIN)/python scripts/bench_scene.py --model $(MODEL) --duration 30 \
		$(if $(BASELINE),--baseline $(BASELINE)) $(if $(TURNS),--turns $(TURNS)) \
		--out results/bench_scene.json

# The SDK adapters' control recovery replayed on the recorded tracks (results/adapter_error.json).
adapter-error: $(STAMP)
	$(BIN)/python scripts/adapter_error.py

bench-sustained: $(STAMP)
	$(BIN)/python scripts/bench.py --model $(MODEL) --sustained-only --sustained-runs 5 \
		--out results/bench_sustained_runs.json

# The coverage audit's cost on the observation: audit on and off side by side (results/bench_audit.json).
bench-audit: $(STAMP)
	$(BIN)/python scripts/bench.py --model $(MODEL) --audit-only

load: $(STAMP)
	$(BIN)/python scripts/load.py --url $(URL) --duration $(DURATION)

# make load's mix at 50 humans x 10 Hz, 2 planners x 10 Hz against a service started here: one
# process, then three replicas behind nginx (make scale-test's topology); results/load_scale.json.
# FRAMES=1: the 50 humans in 6 scenes, each observed in one POST /v1/frames per period and checked
# by a planner of its own, every request with its X-FRT-Scene; results/load_scale_frames.json.
LOAD_SCALE = $(if $(FRAMES),--frames --scenes 6 --planners 1 --out results/load_scale_frames.json,--out results/load_scale.json)
load-scale: $(STAMP)
	$(BIN)/python scripts/load_topology.py --topology single --humans 50 --obs-hz 10 \
		--duration $(DURATION) --label "one process" $(LOAD_SCALE)
	$(BIN)/python scripts/load_topology.py --topology replicas --replicas 3 --humans 50 \
		--obs-hz 10 --duration $(DURATION) --label "three replicas" $(LOAD_SCALE)

# Where the time goes under make load's mix: py-spy samples of the server and its workers.
profile-load: $(STAMP)
	$(BIN)/python scripts/profile_load.py --duration 40 --out results/profile_load.json

scale-test: $(STAMP)
	$(BIN)/python -m pytest -q tests/test_scale_out.py

scenarios: $(STAMP)
	$(BIN)/python -m experiments.run_all

# Choose gamma on DATA's tracks (half to choose, half to report): profiles/$(PROFILE).json,
# results/calibration_$(PROFILE).{json,md}, docs/calibration_$(PROFILE).png (docs/coverage.md).
calibrate: $(STAMP)
	$(BIN)/python -m experiments.calibrate --data $(DATA) --target $(TARGET) --profile $(PROFILE) \
		--model $(MODEL)

# Does confidence rescue a confidently wrong predictor? Recorded cars and pedestrians, each bounds
# rule with confidence on and off, rescue_onset chosen on half the tracks, the other half reported:
# results/rescue.{json,md}, docs/rescue.png (experiments/rescue.py). ARGS=--quick for a short run.
rescue: $(STAMP)
	$(BIN)/python -m experiments.rescue --model $(MODEL) $(ARGS)

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
