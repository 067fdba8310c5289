# make demo         - set everything up and run the demo on the bundled sample data
# make test         - set everything up and run the test suite
# make constraints  - re-resolve the newest releases pyproject.toml allows into constraints.txt
# make fuzz         - run FUZZ_CASES seeded damaged inputs through the commands (minutes)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
PIP    := --quiet --disable-pip-version-check
FUZZ_CASES ?= 10000
FUZZ_SEED  ?= 0

.PHONY: demo test setup syslibs lint bench fuzz constraints clean

demo: setup
	$(VENV)/bin/slamcli demo --out runs/demo --force

test: setup
	$(PY) -m pytest -q -n 2 --dist loadfile

setup: syslibs $(STAMP)

syslibs:
	@sh scripts/ensure-syslibs.sh

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
	  echo "# Regenerate with 'make constraints'; see README.md, 'Installs'."; \
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

clean:
	rm -rf $(VENV) .venv-constraints runs .pytest_cache .mypy_cache .ruff_cache
