# Two commands on a fresh machine: `make demo` and `make test`.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PYTHON ?= python3

.PHONY: demo test setup bench clean

$(STAMP): requirements.lock pyproject.toml scripts/sysdeps.sh
	@bash scripts/sysdeps.sh
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements.lock
	@bash scripts/install-acquisition-deps.sh --python $(PY)
	$(PY) -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
	@touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/inspector demo --out out/demo

test: $(STAMP)
	$(VENV)/bin/pytest -q

clean:
	rm -rf $(VENV) out .pytest_cache

# Accuracy on captures written by another program (tests/acceptance/foreign_capture.py):
# unseen parts x imaging conditions through `inspector run`, table in docs/acceptance.md.
.PHONY: acceptance
acceptance: $(STAMP)
	$(PY) tests/acceptance/run_matrix.py --work out/acceptance --out-md docs/acceptance.md
