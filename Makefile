# terramap: the two commands of the README, plus a few helpers.
#   make demo   install missing Debian packages, build (Release), run the embedded demo
#   make test   install missing Debian packages, build (Release), run every test
#   make bench  build and run the Google Benchmark programs
#   make mutation  break the code on purpose and check the tests notice (docs/testing.md)
#   make install PREFIX=/usr/local
BUILD ?= build
JOBS ?= 2
PREFIX ?= /usr/local
CMAKE_FLAGS ?=
OUT ?= out/demo

.PHONY: all deps configure build demo test bench mutation install clean

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

test: build
	cd $(BUILD) && ctest --output-on-failure -j $(JOBS) --timeout 900

bench: build
	@for b in $(BUILD)/bin/bench_*; do echo "== $$b"; $$b --benchmark_counters_tabular=true || exit 1; done

mutation:
	bash scripts/mutation_check.sh --out docs/testing.md

# --prefix here, not only at configure time: build/ may have been configured with another one.
install: build
	cmake --install $(BUILD) --prefix $(PREFIX)

clean:
	rm -rf $(BUILD) out
