# spherepose: one entry point. The top level delegates to the parts and stops
# at the first failure. `make demo` and `make test` install what is missing.
.DELETE_ON_ERROR:
.PHONY: all deps textures dataset firmware stage host build test demo bench study format clean help

VENV    := .venv
PY      := $(VENV)/bin/python
BUILD   := build
TEXTURE ?= Texture_3_color

help:
	@echo "make demo     install what is missing, build everything, run the simulated rig experiment"
	@echo "make test     install what is missing, build everything, run every test"
	@echo "make deps     Debian packages + .venv from requirements.txt (safe to rerun)"
	@echo "make textures the six paper textures into $(BUILD)/textures"
	@echo "make dataset  the P1 dataset of TEXTURE=$(TEXTURE) into $(BUILD)/dataset/$(TEXTURE)"
	@echo "make firmware | stage | host    build one part"
	@echo "make bench    benchmarks (docs/benchmarks.md)"
	@echo "make study    the six-texture training study (PROFILE=quick|p1)"
	@echo "make format   clang-format the C and C++ of host/, sim/stage/, bench/, tests/ (.clang-format)"
	@echo "make clean    remove build outputs"

deps:
	@scripts/deps.sh

textures: deps
	$(VENV)/bin/textures generate --out $(BUILD)/textures

dataset: textures
	$(VENV)/bin/sim dataset --texture $(BUILD)/textures/$(TEXTURE).png --out $(BUILD)/dataset/$(TEXTURE)

firmware: deps
	$(MAKE) -C firmware

stage: deps
	$(MAKE) -C sim/stage

host: deps
	$(MAKE) -C host
	$(MAKE) -C host/rig

build: firmware stage host

test: deps build
	@tests/run_all.sh

demo: deps build
	@scripts/demo.sh

bench: deps build
	@bench/run_all.sh

PROFILE ?= quick
study: deps
	$(VENV)/bin/posetrain study --profile $(PROFILE) --out $(BUILD)/study-$(PROFILE)

# One C style per area: .clang-format at the top for host/, sim/stage/ and the
# C of bench/ and tests/; firmware/ keeps grbl's layout (its own .clang-format
# turns the formatter off).
FORMATTED = $(shell git ls-files 'host/*.c' 'host/*.h' 'host/*.cpp' 'sim/stage/*.c' 'sim/stage/*.h' \
              'bench/*.c' 'tests/host/*.c' 'tests/host/*.h' 'tests/stage/*.c')
format:
	@command -v clang-format >/dev/null || { echo "make format: clang-format is missing (apt-get install clang-format)" >&2; exit 1; }
	clang-format -i $(FORMATTED)

clean:
	-$(MAKE) -C firmware clean
	-$(MAKE) -C sim/stage clean
	-$(MAKE) -C host clean
	-$(MAKE) -C host/rig clean
	rm -rf $(BUILD)
