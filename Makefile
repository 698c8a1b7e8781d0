# pointviz — set-up, build, demo and tests on a fresh Debian machine.
#   make demo   build everything, render the built-in scene, write a report under out/
#   make test   build everything and run the test suite (GUI and browser tests under Xvfb)
PY ?= python3
PIP ?= $(PY) -m pip
# Debian packages: compiler and CMake for the core; Embree for the point baseline in benchmarks;
# Xvfb + Mesa's software Vulkan for the Open3D viewer; Chromium to check HTML reports; ffmpeg.
APT_PACKAGES = g++ cmake make libembree-dev xvfb xauth libvulkan1 mesa-vulkan-drivers \
               libusb-1.0-0 libgomp1 chromium ffmpeg
PYTEST_ARGS ?=

.PHONY: all deps build demo test test-fast sanitize bench clean

all: build

deps: build/.deps-stamp

build/.deps-stamp: Makefile pyproject.toml
	@missing=""; for p in $(APT_PACKAGES); do dpkg -s $$p >/dev/null 2>&1 || missing="$$missing $$p"; done; \
	if [ -n "$$missing" ]; then \
	  echo "installing Debian packages:$$missing"; \
	  SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
	  $$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi
	$(PIP) install -q "scikit-build-core>=0.10" "nanobind>=2.0"
	@mkdir -p build && touch $@

build: deps
	$(PIP) install -q --no-build-isolation -e ".[all]"

demo: build
	$(PY) -m pointviz.demo --out out

test: build
	xvfb-run -a -s "-screen 0 1600x1000x24" $(PY) -m pytest -q -ra $(PYTEST_ARGS)

test-fast: build
	$(PY) -m pytest -q -ra -m "not slow and not gui" $(PYTEST_ARGS)

# The C++ core's tests under AddressSanitizer + UndefinedBehaviorSanitizer, twice: with the
# run-time dispatched kernels (every instruction set this CPU has, each checked against the
# portable one) and scalar only (no SIMD anywhere).
SANITIZE_ENV = ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1
sanitize: deps
	cmake -S tests/cpp -B build/sanitize -DCMAKE_BUILD_TYPE=Debug -DPOINTVIZ_SANITIZE=ON -DPOINTVIZ_SCALAR=OFF >/dev/null
	cmake --build build/sanitize -j2
	$(SANITIZE_ENV) ./build/sanitize/core_tests
	$(SANITIZE_ENV) ./build/sanitize/wide_tests
	$(SANITIZE_ENV) ./build/sanitize/kdtree_tests
	$(SANITIZE_ENV) ./build/sanitize/reader_tests
	$(SANITIZE_ENV) ./build/sanitize/preprocess_tests
	$(SANITIZE_ENV) ./build/sanitize/depth_tests
	cmake -S tests/cpp -B build/sanitize-scalar -DCMAKE_BUILD_TYPE=Debug -DPOINTVIZ_SANITIZE=ON -DPOINTVIZ_SCALAR=ON >/dev/null
	cmake --build build/sanitize-scalar -j2
	$(SANITIZE_ENV) ./build/sanitize-scalar/core_tests
	$(SANITIZE_ENV) ./build/sanitize-scalar/wide_tests
	$(SANITIZE_ENV) ./build/sanitize-scalar/kdtree_tests
	$(SANITIZE_ENV) ./build/sanitize-scalar/reader_tests
	$(SANITIZE_ENV) ./build/sanitize-scalar/preprocess_tests
	$(SANITIZE_ENV) ./build/sanitize-scalar/depth_tests

bench: build
	$(PY) benchmarks/bench_core.py

clean:
	rm -rf build out *.egg-info
