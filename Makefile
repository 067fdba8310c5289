# make demo         - set everything up and run the demo on the bundled sample data
# make test         - set everything up and run the test suite (it prints the 15 slowest tests)
# make test-robust  - each accuracy test again on perturbed inputs and seeds 0-4, mono 0-9 (34 CPU-minutes)
# make constraints  - re-resolve the newest releases pyproject.toml allows into constraints.txt
# make fuzz         - run FUZZ_CASES seeded damaged inputs through the commands (minutes)
# make vocabulary   - retrain the shipped ORB vocabulary slamcli/data/orb_vocabulary.npz (~20 min)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
PIP    := --quiet --disable-pip-version-check
FUZZ_CASES ?= 10000
FUZZ_SEED  ?= 0

.PHONY: demo test setup syslibs bytecode kernels lint bench fuzz constraints clean vocabulary

demo: setup
	$(VENV)/bin/slamcli demo --out runs/demo --force

test: setup
	$(PY) -m pytest -q -n 2 --dist loadfile --durations=15

# Accuracy that does not hinge on last bits (docs/development.md): tests/robust is collected
# only when named. Tests of one seed share its rendering, so they go to one process (loadgroup).
.PHONY: test-robust
test-robust: setup
	$(PY) -m pytest -q -n 2 --dist loadgroup --durations=10 tests/robust

setup: syslibs $(STAMP) bytecode kernels

syslibs:
	@sh scripts/ensure-syslibs.sh

# Where PYTHONDONTWRITEBYTECODE is set, Python never caches slamcli's own modules, and every
# process (each run, each side process) would compile them again; compiled here, they are read.
bytecode: $(STAMP)
	@$(PY) -m compileall -q slamcli

# numba compiles the path search, the car-like planner, the matchers and the renderer on their
# first call (about 40 s in all, on 2 cores) and caches the machine code beside each module.
# Compiled here once per install, and again when a kernel module changes, so neither the demo,
# the tests nor the timings they print pay for it.
KERNELS := $(VENV)/.kernels
kernels: $(KERNELS)
$(KERNELS): $(STAMP) slamcli/kernels.py \
            $(shell grep -rl --include='*.py' '^@numba.njit.*cache=True' slamcli)
	@$(VENV)/bin/slamcli kernels
	@touch $@

# Installs are reproducible: every package comes at the exact version constraints.txt names, so
# a fresh clone gets what the suite last passed with. pyproject.toml keeps ranges for users.
$(STAMP): pyproject.toml constraints.txt
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install $(PIP) -c constraints.txt -e '.[test]'
	@touch $(STAMP)

# A deliberate upgrade: resolve in a scratch environment, then run `make test` and commit
# constraints.txt together with whatever the new versions required.
constraints:
	rm -rf .venv-constraints
	$(PYTHON) -m venv .venv-constraints
	.venv-constraints/bin/python -m pip install $(PIP) -e '.[test]'
	{ echo "# Exact versions make and CI install with (pip install -c constraints.txt)."; \
	  echo "# Regenerate with 'make constraints'; see docs/development.md, 'Installs'."; \
	  .venv-constraints/bin/python -m pip freeze --exclude-editable; } > constraints.txt.new
	mv constraints.txt.new constraints.txt
	rm -rf .venv-constraints

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

bench: setup
	@for f in benchmarks/bench_*.py; do echo "== $$f"; $(PY) $$f || exit 1; done

# Problem cases are saved under runs/fuzz/<case id>/ with the damaged input and what went wrong.
fuzz: setup
	$(PY) tests/fuzzing.py --cases $(FUZZ_CASES) --seed $(FUZZ_SEED) --keep runs/fuzz

# The shipped vocabulary, byte for byte: four rendered rooms (seeds 1-4, two with sensor noise)
# and Open3D's MIT-licensed test frames; never the TUM freiburg1_rpy excerpt, the accuracy test.
# Provenance and licences: slamcli/data/VOCABULARY.md.
VOCAB_DATA ?= ../shared/data/rgbd/open3d_test_data_RGBD
vocabulary: setup
	@tmp=$$(mktemp -d) && trap 'rm -rf "$$tmp"' EXIT && \
	for s in 1 2 3 4; do \
	  if [ $$s -le 2 ]; then noise=--no-noise; else noise=--noise; fi; \
	  $(VENV)/bin/slamcli synth rgbd $$tmp/room$$s --frames 360 --size 640x480 --seed $$s $$noise \
	    || exit 1; \
	done && \
	$(VENV)/bin/slamcli vocab train $$tmp/room1 $$tmp/room2 $$tmp/room3 $$tmp/room4 \
	  $(VOCAB_DATA)/color/*.jpg $(VOCAB_DATA)/other_formats/TUM_color.png \
	  $(VOCAB_DATA)/other_formats/SUN_color.jpg $(VOCAB_DATA)/other_formats/NYU_color.ppm \
	  --every 6 --features 1000 --branching 10 --levels 4 --seed 0 \
	  --out slamcli/data/orb_vocabulary.npz --force

clean:
	rm -rf $(VENV) .venv-constraints runs .pytest_cache .mypy_cache .ruff_cache
