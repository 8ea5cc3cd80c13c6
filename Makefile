# The README's commands are targets here. Each creates the environment it needs.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
CONSTRAINTS := constraints/lock.txt
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml Makefile $(CONSTRAINTS) | cksum | cut -d' ' -f1)

.PHONY: demo test test-slow test-gpu bench lint format clean chromium postgresql gpu-wheels gpu-check gpu-train

$(STAMP): pyproject.toml Makefile $(CONSTRAINTS)
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch's CPU build first (a local wheel, else PyTorch's CPU index): a plain `torch==2.13.0`
	# resolves to the CUDA build (2.7 GB of NVIDIA packages). Where neither is reachable, say so.
	$(PY) -m pip install -q "torch==2.13.0+cpu" 2>/dev/null \
	  || $(PY) -m pip install -q "torch==2.13.0+cpu" --extra-index-url https://download.pytorch.org/whl/cpu 2>/dev/null \
	  || { echo "note: torch's CPU build is not reachable here; installing torch 2.13.0 from PyPI (CUDA build)"; \
	       $(PY) -m pip install -q "torch==2.13.0"; }
	$(PY) -m pip install -q -c $(CONSTRAINTS) -e ".[dev]"
	# optional peer evaluators for the equality tests; --no-deps: their declared deps (GUI, unpinned torch) are not needed
	$(PY) -m pip install -q --no-deps semantic-kitti-api==0.1 nuscenes-devkit==1.2.0
	rm -f $(VENV)/.installed-*
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/dsnet demo

# the dashboard's browser test drives a real headless Chromium (Debian's package)
chromium:
	test -x /usr/bin/chromium || { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium; }

test: $(STAMP) chromium
	$(PY) -m ruff check .
	$(PY) -m pytest -q -m "not slow and not gpu"

# the production recipe's slow test makes its own PostgreSQL cluster (Debian's package; initdb, pg_ctl);
# only the slow tests need it, and that test says why it is skipped where it is missing
postgresql:
	ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q postgresql; }

test-slow: $(STAMP) postgresql
	$(PY) -m pytest -q -m "slow"

# the CUDA paths against the CPU ones; needs a CUDA build of torch and a GPU (skipped otherwise)
test-gpu: $(STAMP)
	$(PY) -m pytest -q -m "gpu" tests/gpu

# A GPU machine without a package registry (docs/gpu.md). These run with that machine's own
# python3 and its CUDA torch: no .venv. `make gpu-wheels` runs first where PyPI is reachable and
# fills $(GPU_WHEELS) (ignored by git, carried to the machine); the other two install those wheels
# into a temporary target. DEVICE=cpu is their smoke mode on a machine without a GPU.
GPU_PYTHON ?= python3
GPU_PYVER ?= 3.12
GPU_WHEELS ?= gpu-wheels
DEVICE ?= cuda
gpu-wheels:
	$(PYTHON) gpu/gpu_wheels.py download --dest $(GPU_WHEELS) --python-version $(GPU_PYVER)

gpu-check:
	$(GPU_PYTHON) gpu/gpu_check.py --device $(DEVICE) --wheels $(GPU_WHEELS) $(ARGS)

gpu-train:
	@test -n "$(OUT)" || { echo "usage: make gpu-train OUT=DIR (a new folder, or one to resume)"; exit 2; }
	$(GPU_PYTHON) gpu/gpu_train.py --out $(OUT) --device $(DEVICE) --wheels $(GPU_WHEELS) $(ARGS)

# every benchmark; gpu/bench_gpu.py last (without CUDA it says so in one line and skips)
bench: $(STAMP)
	for f in bench/bench_*.py gpu/bench_gpu.py; do echo "== $$f"; $(PY) $$f || exit 1; done

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

format: $(STAMP)
	$(PY) -m ruff format .
	$(PY) -m ruff check --fix .

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache
