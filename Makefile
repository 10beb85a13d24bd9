# Two user-facing targets: `make demo` (main job) and `make test`. Both create .venv when missing.
VENV   ?= .venv
PY     := $(VENV)/bin/python
# The CPU build of torch on this machine's find-links; a torch already in the venv (e.g. a CUDA build) is kept.
TORCH  ?= torch==2.13.0
STAMP  := $(VENV)/.solidkit-installed

.PHONY: demo test test-slow bench clean-venv system-deps

$(STAMP): pyproject.toml constraints.txt
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -c "import torch" 2>/dev/null || $(PY) -m pip install -q "$(TORCH)"
	$(PY) -m pip install -q -c constraints.txt -e ".[test]"
	@command -v chromium >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && apt-get update -qq && apt-get install -y -qq chromium >/dev/null; } || echo "note: Debian chromium not installed; the labeling browser tests will skip"
	@ls /usr/lib/*/libLLVM-19.so* >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && apt-get update -qq && apt-get install -y -qq libllvm19 >/dev/null; } || echo "note: libLLVM 19 not installed (needs root and apt); Mitsuba (solidkit synth) falls back to its slow scalar_rgb variant; make demo does not render"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/solidkit demo --out demo_out

# ruff (lint + formatting) first (a second), then mypy (strict on the bottom layers) beside the suite: both must pass.
test: $(STAMP)
	$(VENV)/bin/ruff check solidkit tests benchmarks
	$(VENV)/bin/ruff format --check solidkit tests benchmarks
	$(VENV)/bin/mypy & checker=$$!; $(PY) -m pytest -q -n 2 -p no:cacheprovider; tests=$$?; wait $$checker && exit $$tests

test-slow: $(STAMP)
	$(PY) -m pytest -q -n 2 -p no:cacheprovider -m slow

bench: $(STAMP)
	$(PY) -m pip install -q -c constraints.txt -e ".[test,bench]"
	$(PY) benchmarks/run.py

clean-venv:
	rm -rf $(VENV)

# Optional: Debian's LLVM 19 for Mitsuba's llvm_ad_rgb variant (solidkit.synth; LLVM 14/15 crash in drjit).
# Without it solidkit.synth falls back to scalar_rgb (slow); make test does not need it.
system-deps:
	apt-get update && apt-get install -y libllvm19
