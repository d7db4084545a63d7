# The README's commands. Every target builds its own virtualenv from the repo's files.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
# pytest-xdist processes for `make test`: the suite waits more than it computes (servers, Ray and
# subprocesses starting), so three share even 2 cores well (two left a third of the cores idle:
# docs/BENCHMARKS.md, "Test suite time"); each test file stays on one process.
TEST_PROCESSES ?= 3

.PHONY: install browser compiler gl mitsuba demo test bench report clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	# torch first, pinned: the CPU wheel is cached on these machines; a looser pin pulls CUDA.
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

# The whole stack on the embedded default: neuenh serve (local Ray, SQLite and artifacts under
# runs/demo), the quickstart job submitted with neuenh-client submit --wait, then the service stopped.
demo: $(STAMP)
	$(PY) examples/service_demo.py

# The dashboard's browser test drives Debian's Chromium through Playwright (test tools' own
# browser downloads do not work here). Installed when missing and root; else that test skips.
browser:
	@command -v chromium >/dev/null || { [ "$$(id -u)" = 0 ] && \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >/dev/null; } || \
	  echo "note: chromium is not installed and this is not root; the dashboard browser test will skip"

# torch.compile (the opt-in compiled training step, train.compile) builds C++ kernels with g++.
compiler:
	@command -v g++ >/dev/null || { [ "$$(id -u)" = 0 ] && \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends g++ >/dev/null; } || \
	  echo "note: g++ is not installed and this is not root; the compiled-training test will skip"

# The GLSL export is compiled by Khronos' glslangValidator and run on Mesa's llvmpipe through
# headless EGL (moderngl). Installed when missing and root; else those tests skip.
gl:
	@{ command -v glslangValidator >/dev/null && ls /usr/lib/x86_64-linux-gnu/libEGL_mesa.so.0 >/dev/null 2>&1; } || \
	  { [ "$$(id -u)" = 0 ] && apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	    --no-install-recommends glslang-tools libegl1 libegl-mesa0 libgl1-mesa-dri >/dev/null; } || \
	  echo "note: glslang-tools or Mesa's EGL is not installed and this is not root; the GLSL export tests will skip"

# Mitsuba's LLVM variant (the Mitsuba export) JIT-compiles with the system's libLLVM, version 17 or
# newer (Debian 12's Mesa brings 15, which Dr.Jit's kernels crash). Installed when missing and root;
# else those tests skip.
mitsuba: $(STAMP)
	@$(PY) -c "from neuenh.export.mitsuba import find_libllvm; raise SystemExit(find_libllvm() is None)" || \
	  { [ "$$(id -u)" = 0 ] && apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	    --no-install-recommends libllvm19 >/dev/null; } || \
	  echo "note: libLLVM 17+ is not installed and this is not root; the Mitsuba export tests will skip"

# The dashboard's pure modules under Node's own test runner, then every Python test (in
# TEST_PROCESSES processes, a file per process at a time, the heaviest files first: tests/conftest.py)
# with the 25 slowest listed (make them cheaper before adding more).
test: $(STAMP) browser compiler gl mitsuba
	@if command -v node >/dev/null; then node --test tests/dashboard/; \
	  else echo "note: node is not installed; the dashboard's unit tests (tests/dashboard) skip"; fi
	$(PY) -m pytest -q -n $(TEST_PROCESSES) --dist loadfile --no-loadscope-reorder --durations=25

# Slow, measured side by side; each script rewrites its own section of docs/BENCHMARKS.md.
# bench_fit runs the checkout before issue 13 beside this one, both fitting the model shipped then.
ISSUE13_MODEL := e388c1a
# bench_plain_fit runs the plain fit as it was before issue 24's warm-up subset and L-BFGS restart beside today's.
PLAIN_FIT_BEFORE := 0709a17
# bench_fit_compile runs the jit kernel as it was before its code read no count of rows (stop 81) beside today's.
FIT_COMPILE_BEFORE := f3c8d3c
bench: $(STAMP)
	$(PY) bench/bench_core.py --write docs/BENCHMARKS.md
	$(PY) bench/bench_data.py --write docs/BENCHMARKS.md
	$(PY) bench/bench_speed.py --compile --write docs/BENCHMARKS.md
	mkdir -p build/issue13-model && for f in model.json weights.safetensors materials.safetensors; do \
	  git show $(ISSUE13_MODEL):models/enhanced-ggx/$$f > build/issue13-model/$$f; done
	$(PY) bench/bench_fit.py --model build/issue13-model --before-rev 351a26c --write docs/BENCHMARKS.md
	$(PY) bench/bench_plain_fit.py --before-rev $(PLAIN_FIT_BEFORE) --write docs/BENCHMARKS.md
	$(PY) bench/bench_fit_memory.py --write docs/BENCHMARKS.md
	$(PY) bench/bench_fit_compile.py --before-rev $(FIT_COMPILE_BEFORE) --write docs/BENCHMARKS.md
	$(PY) bench/bench_search.py --write docs/BENCHMARKS.md
	$(PY) bench/bench_api.py --write docs/BENCHMARKS.md
	$(PY) bench/bench_cluster.py --write docs/BENCHMARKS.md
	$(PY) bench/bench_shared_cluster.py --write docs/BENCHMARKS.md
	$(PY) bench/bench_export.py --write docs/BENCHMARKS.md

# docs/RESULTS.md, docs/results.json and docs/img/results/: every model on the RGL materials
# (../shared/data/rgl) with the shipped models/enhanced-ggx and models/baselines; about half an hour.
report: $(STAMP)
	$(VENV)/bin/neuenh report --efficiency

clean:
	rm -rf $(VENV) build *.egg-info .inductor-cache
