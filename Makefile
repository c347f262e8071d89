# pcr_pro — top-level convenience targets.
#   make demo   install missing Debian packages, build, run the main job on shipped data
#   make test   install missing Debian packages, build, run all tests (ctest)
#   make build  configure (once) and build only
#   make bench  build and run the benchmarks, regenerate docs/BENCHMARKS.md (BENCH_ARGS=--quick for a short run,
#               BENCH_ARGS=--node for the node section alone: the real LSD-SLAM bags merged through merge_node,
#               BENCH_ARGS="--only real,simulated [--ours-only]" for some suite sections into build/bench_sections)
#   The real two-agent cases are built with the build, from PCR_PRO_DATA_DIR (docs/FORMATS.md).
# Debian's /usr/bin comes first on PATH: a pyenv python3 would break catkin.
SHELL := /bin/bash
export PATH := /usr/bin:/bin:/usr/sbin:/sbin:$(PATH)

BUILD_DIR ?= build
BUILD_TYPE ?= Release
JOBS ?= 2
# Extra cmake -D options for the first configure, e.g. CMAKE_ARGS=-DPCR_PRO_DATA_DIR=/path/to/data
CMAKE_ARGS ?=

.PHONY: all deps configure build test demo bench clean

all: build

deps:
	@scripts/install_deps.sh build

$(BUILD_DIR)/CMakeCache.txt:
	cmake -S . -B $(BUILD_DIR) -DCMAKE_BUILD_TYPE=$(BUILD_TYPE) -DCATKIN_DEVEL_PREFIX=$(CURDIR)/$(BUILD_DIR)/devel $(CMAKE_ARGS)

configure: $(BUILD_DIR)/CMakeCache.txt

build: configure
	cmake --build $(BUILD_DIR) -j $(JOBS)

test: deps
	@$(MAKE) --no-print-directory build
	cd $(BUILD_DIR) && ctest --output-on-failure -j $(JOBS)

demo: deps
	@$(MAKE) --no-print-directory build
	scripts/demo.sh $(BUILD_DIR)

bench:
	@scripts/install_deps.sh bench
	@$(MAKE) --no-print-directory build
	scripts/bench.sh $(BUILD_DIR) $(BENCH_ARGS)

# --- hardening (issue 6) -------------------------------------------------------------------
#   make fuzz           build the libFuzzer targets (clang, build-fuzz/) and run each for FUZZ_SECONDS
#   make test-sanitize  the unit tests and the master-free ROS tests under ASan + UBSan (build-asan/)
FUZZ_SECONDS ?= 60
.PHONY: fuzz test-sanitize

fuzz:
	@scripts/install_deps.sh fuzz
	FUZZ_SECONDS=$(FUZZ_SECONDS) JOBS=$(JOBS) scripts/fuzz.sh $(FUZZ_TARGETS)

test-sanitize:
	@scripts/install_deps.sh sanitize
	JOBS=$(JOBS) scripts/sanitize.sh

#   make soak           the merge node's soak test for SOAK_SECONDS (default 600) with SOAK_INPUT
#                       (pcr_pro | lsd_slam); `make test` runs it for 60 s with pcr_pro input
SOAK_SECONDS ?= 600
SOAK_INPUT ?= pcr_pro
.PHONY: soak
soak: deps
	@$(MAKE) --no-print-directory build
	source $(BUILD_DIR)/devel/setup.bash && rostest $(CURDIR)/test/ros/soak.test seconds:=$(SOAK_SECONDS) \
	  input:=$(SOAK_INPUT) report:=$(CURDIR)/$(BUILD_DIR)/soak_report_$(SOAK_INPUT)_$(SOAK_SECONDS)s.txt
	@cat $(BUILD_DIR)/soak_report_$(SOAK_INPUT)_$(SOAK_SECONDS)s.txt
# --- end of hardening ----------------------------------------------------------------------

clean:
	rm -rf $(BUILD_DIR)
