# posturemap: `make demo` sets everything up and runs the pipeline; `make test` runs the tests
# (the quick set, under a minute); `make test-slow` the slow ones; `make test-all` both (CI).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip --disable-pip-version-check -q
# The real mocap (bandai1/, cmu/) for the tests and `make bench`: next to the repository unless set.
export POSTUREMAP_DATA ?= $(abspath ../shared/data)

.PHONY: demo test test-slow test-all bench bench-quick serve clean web studio-docs wheel-smoke

# The package with what `demo` and `serve` use (the studio's server, the filmstrip pictures).
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install -e '.[web,preview]'
	touch $@

$(VENV)/.test-installed: $(VENV)/.installed pyproject.toml
	$(PIP) install -e '.[test]'
	touch $@

demo: $(VENV)/.installed
	$(VENV)/bin/posturemap demo
	@echo
	@echo "posturemap is installed in $(VENV): 'source $(VENV)/bin/activate' puts it on the PATH"
	@echo "(or call $(VENV)/bin/posturemap). 'make serve' opens the studio on the demo's clips."

# three.js for the studio page, pinned in package.json/package-lock.json, copied next to the page
# (no CDN: the page works offline; GLTFLoader for the tests' glTF checks). `make web` is enough
# after a fresh clone. `npm ci` also installs the Khronos glTF-Validator (devDependencies) for the tests.
VENDOR := src/posturemap/web/static/vendor
THREE := node_modules/three

node_modules/.package-lock.json: package.json package-lock.json
	npm ci --no-audit --no-fund --loglevel=error
	touch $@

$(VENDOR)/.stamp: node_modules/.package-lock.json
	rm -rf $(VENDOR)
	mkdir -p $(VENDOR)/addons/controls $(VENDOR)/addons/loaders $(VENDOR)/addons/utils
	cp $(THREE)/build/three.module.js $(THREE)/build/three.core.js $(THREE)/LICENSE $(VENDOR)/
	cp $(THREE)/examples/jsm/controls/OrbitControls.js $(VENDOR)/addons/controls/
	cp $(THREE)/examples/jsm/loaders/BVHLoader.js $(THREE)/examples/jsm/loaders/GLTFLoader.js $(VENDOR)/addons/loaders/
	cp $(THREE)/examples/jsm/utils/BufferGeometryUtils.js $(THREE)/examples/jsm/utils/SkeletonUtils.js $(VENDOR)/addons/utils/
	touch $@

web: $(VENDOR)/.stamp

# The quick set (under a minute on 2 cores). Tests marked `slow` (longer fuzzing, the full-size
# quick benchmark, more transitions on real clips, ...) run in `test-slow`; CI (.ci/run) runs both.
test: $(VENV)/.test-installed web
	$(PY) -m pytest -q -m "not slow"

test-slow: $(VENV)/.test-installed web
	$(PY) -m pytest -q -m slow

test-all: $(VENV)/.test-installed web
	$(PY) -m pytest -q

# The evaluation (docs/results.md is a full run's output) and the studio.
bench: $(VENV)/.test-installed
	$(VENV)/bin/posturemap bench --out bench-results

bench-quick: $(VENV)/.test-installed
	$(VENV)/bin/posturemap bench --quick --out bench-results

# The studio on the demo's clips and map (after `make demo`), else on the bundled sample.
serve: $(VENV)/.installed web
	@if [ -f out/map.npz ]; then set -x; \
	    $(VENV)/bin/posturemap serve out/sample_walk.bvh out/sample_run.bvh out/sample_wave.bvh --map out/map.npz; \
	else set -x; $(VENV)/bin/posturemap serve; fi

# Build the wheel, install it in a fresh venv outside the checkout, run the demo and the studio.
wheel-smoke:
	bash .ci/wheel-smoke

# Re-measure the studio's slider latency and retake its screenshot (docs/web-latency.md, docs/studio.png).
studio-docs: $(VENV)/.test-installed web
	$(PY) bench/studio_latency.py --doc docs/web-latency.md
	POSTUREMAP_UPDATE_DOCS=1 $(PY) -m pytest -q tests/test_browser.py -k screenshot

clean:
	rm -rf $(VENV) out out-* build dist src/*.egg-info node_modules $(VENDOR)
