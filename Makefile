# make demo  - set everything up and run the demo on the bundled sample data
# make test  - set everything up and run the test suite
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: demo test setup syslibs lint bench clean

demo: setup
	$(VENV)/bin/slamcli demo --out runs/demo --force

test: setup
	$(PY) -m pytest -q -n 2 --dist loadfile

setup: syslibs $(STAMP)

syslibs:
	@sh scripts/ensure-syslibs.sh

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -e '.[test]'
	@touch $(STAMP)

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

bench: setup
	@for f in benchmarks/bench_*.py; do echo "== $$f"; $(PY) $$f || exit 1; done

clean:
	rm -rf $(VENV) runs .pytest_cache .mypy_cache .ruff_cache
