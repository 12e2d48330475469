# Two commands do all the set-up on a fresh machine:
#   make demo   creates .venv, installs ushape, runs the quickstart experiment on synthetic data
#   make test   creates .venv, installs ushape with test extras, runs the test suite (CI runs this)
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.ushape-installed

.PHONY: install demo test test-slow lint format bench device-check gallery clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -e '.[dev]' > $(VENV)/pip-install.log 2>&1 \
	  || { grep -v 'is ignored: it is neither' $(VENV)/pip-install.log; exit 1; }
	$(PY) -c "import ushape, lightning, torchvision; print('ushape env ok: torch', __import__('torch').__version__)"
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(PY) train.py experiment=quickstart $(ARGS)

# One pytest worker per core (pytest-xdist), each on one thread (tests/conftest.py).
test: install
	$(PY) -m pytest -q -m "not slow" -n auto $(ARGS)

test-slow: install
	$(PY) -m pytest -q -m slow -n auto $(ARGS)

lint: install
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

format: install
	$(PY) -m ruff format .
	$(PY) -m ruff check --fix .

bench: install
	$(PY) bench.py $(ARGS)

# On a GPU machine, ~8 minutes: the paper preset on R2N2 chairs timed into one JSON (docs/r2n2.md).
device-check: install
	$(PY) -m ushape.bench.device_check $(if $(VOXELS),--voxels-root $(VOXELS)) $(if $(WEIGHTS),--weights-path $(WEIGHTS)) $(ARGS)

gallery: install
	$(VENV)/bin/ushape gallery $(ARGS)

clean:
	rm -rf $(VENV) outputs multirun .pytest_cache
