# fascicle — set-up, build, test and demo in one place. See README.md.
BUILD ?= build
JOBS ?= $(shell nproc)
CMAKE_FLAGS ?= -DCMAKE_BUILD_TYPE=Release

.PHONY: deps configure build test demo bench asan clean viewer

deps:
	@bash scripts/install-deps

$(BUILD)/CMakeCache.txt:
	cmake -S . -B $(BUILD) $(CMAKE_FLAGS)

configure: deps $(BUILD)/CMakeCache.txt

build: configure viewer
	cmake --build $(BUILD) -j $(JOBS)

# The browser viewer (viewer/, docs/viewer.md): npm ci when node_modules is missing or older than the
# lock file, vite build when a source is newer than dist/viewer.js.
VIEWER_SOURCES := $(shell find viewer/src -type f 2>/dev/null) viewer/package.json viewer/tsconfig.json viewer/vite.config.ts
viewer/node_modules/.package-lock.json: viewer/package-lock.json
	cd viewer && npm ci --no-audit --no-fund
viewer/dist/viewer.js: viewer/node_modules/.package-lock.json $(VIEWER_SOURCES)
	cd viewer && npm run build
viewer: viewer/dist/viewer.js

test: build
	ctest --test-dir $(BUILD) --output-on-failure -j $(JOBS)

demo: build
	$(BUILD)/bin/fascicle demo --out out/demo
	@echo "demo written to out/demo: open out/demo/report.html in a browser, or out/demo/demo.pvd in ParaView"

bench: build
	@mkdir -p out/bench
	@for b in $(BUILD)/bin/bench_*; do echo "== $$b"; $$b --benchmark_out=out/bench/$$(basename $$b).json --benchmark_out_format=json; done

# Unit tests once more under AddressSanitizer + UndefinedBehaviorSanitizer (used by .ci/run).
asan: deps
	cmake -S . -B build-asan -DCMAKE_BUILD_TYPE=RelWithDebInfo -DFASCICLE_SANITIZE=ON -DFASCICLE_BUILD_BENCH=OFF
	cmake --build build-asan -j $(JOBS) --target fascicle_unit_tests
	ASAN_OPTIONS=detect_leaks=0:allocator_may_return_null=1 UBSAN_OPTIONS=print_stacktrace=1 ctest --test-dir build-asan --output-on-failure -j $(JOBS)

clean:
	rm -rf $(BUILD) build-asan
