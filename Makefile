# terramap: the two commands of the README, plus a few helpers.
#   make demo   install missing Debian packages, build (Release), run the embedded demo
#   make test   install missing Debian packages, build (Release), run every test
#   make test-asan  every test under AddressSanitizer + UndefinedBehaviorSanitizer
#   make test-tsan  every test under ThreadSanitizer (docs/reliability.md)
#   make fuzz   libFuzzer on every reader, FUZZ_SECONDS (600) each; FUZZ_TARGETS="fuzz_pcd ..." for some
#   make bench  build and run the Google Benchmark programs
#   make mutation  break the code on purpose and check the tests notice (docs/testing.md)
#   make install PREFIX=/usr/local
# bash for pipefail: `make test` tees CTest's output and keeps its exit status.
SHELL := /bin/bash
BUILD ?= build
JOBS ?= 2
PREFIX ?= /usr/local
CMAKE_FLAGS ?=
OUT ?= out/demo

.PHONY: all deps configure build demo test test-asan test-tsan fuzz bench mutation install clean

all: build

deps:
	@bash scripts/install_deps.sh

$(BUILD)/build.ninja:
	cmake -S . -B $(BUILD) -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_INSTALL_PREFIX=$(PREFIX) $(CMAKE_FLAGS)

configure: deps $(BUILD)/build.ninja

build: configure
	cmake --build $(BUILD) -j $(JOBS)

demo: build
	$(BUILD)/bin/terramap run --out $(OUT)
	@echo "demo outputs in $(OUT): map.tif (GeoTIFF), *.png, map.tmap, report.json"

# Then the tests that were skipped and why (e.g. the KITTI frames absent: data/README.md), and
# CTest's summary line once more, so the output still ends with it (CI reads the closing line).
test: build
	cd $(BUILD) && { set -o pipefail; ctest --output-on-failure -j $(JOBS) --timeout 900 --output-junit ctest.xml \
	  2>&1 | tee ctest.log; rc=$$?; python3 $(CURDIR)/scripts/ctest_skips.py ctest.xml; \
	  grep -E '^[0-9]+% tests passed, [0-9]+ tests? failed out of [0-9]+' ctest.log | tail -n 1; exit $$rc; }

# Every test under AddressSanitizer + UndefinedBehaviorSanitizer in its own tree (build-asan).
# Python and the web view are off there (an uninstrumented interpreter or browser cannot load an
# instrumented module); the ASan-host and TSan sub-builds are tests of the plain build.
SAN_FLAGS = -DTERRAMAP_WITH_PYTHON=OFF -DTERRAMAP_WITH_WEB=OFF -DTERRAMAP_TEST_SANITIZED_HOST=OFF \
            -DTERRAMAP_TEST_TSAN_ENGINE=OFF -DTERRAMAP_BUILD_BENCHMARKS=OFF
test-asan: deps
	cmake -S . -B build-asan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTERRAMAP_SANITIZE=address,undefined $(SAN_FLAGS)
	cmake --build build-asan -j $(JOBS)
	cd build-asan && ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=halt_on_error=1:print_stacktrace=1 \
	  ctest --output-on-failure -j $(JOBS) --timeout 1800 $(CTEST_ARGS)

# Every test under ThreadSanitizer in its own tree (build-tsan). Executor and the simulator run
# their tasks on std::threads there (Debian's TBB is not instrumented; docs/reliability.md);
# libtorch is not instrumented either and keeps its own thread pool, so the torch plugins are off.
TSAN_OPTIONS = halt_on_error=1:second_deadlock_stack=1:suppressions=$(CURDIR)/scripts/tsan.supp
test-tsan: deps
	cmake -S . -B build-tsan -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DTERRAMAP_SANITIZE=thread \
	  -DTERRAMAP_WITH_TORCH=OFF $(SAN_FLAGS)
	# The build runs every test binary to list its tests (gtest_discover_tests): under TSan too.
	TSAN_OPTIONS=$(TSAN_OPTIONS) cmake --build build-tsan -j $(JOBS)
	cd build-tsan && TSAN_OPTIONS=$(TSAN_OPTIONS) ctest --output-on-failure -j $(JOBS) --timeout 3600 $(CTEST_ARGS)

# One libFuzzer target per reader (fuzz/), built with clang in build-fuzz/; findings are kept in
# build-fuzz/artifacts/<target>/ and fail the run (docs/reliability.md, "Fuzzing").
FUZZ_SECONDS ?= 600
FUZZ_JOBS ?= 1
FUZZ_TARGETS ?=
fuzz:
	@bash scripts/install_deps.sh fuzz
	FUZZ_SECONDS=$(FUZZ_SECONDS) FUZZ_JOBS=$(FUZZ_JOBS) FUZZ_TARGETS="$(FUZZ_TARGETS)" JOBS=$(JOBS) bash scripts/fuzz.sh

bench: build
	@for b in $(BUILD)/bin/bench_*; do echo "== $$b"; $$b --benchmark_counters_tabular=true || exit 1; done

mutation:
	bash scripts/mutation_check.sh --out docs/testing.md

# --prefix here, not only at configure time: build/ may have been configured with another one.
install: build
	cmake --install $(BUILD) --prefix $(PREFIX)

clean:
	rm -rf $(BUILD) out
