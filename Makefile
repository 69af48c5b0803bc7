# Two commands on a fresh machine: `make demo` and `make test`.
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-stamp
PYTHON ?= python3

.PHONY: demo test setup bench clean docs

$(STAMP): requirements.lock pyproject.toml scripts/sysdeps.sh
	@bash scripts/sysdeps.sh
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements.lock
	@bash scripts/install-acquisition-deps.sh --python $(PY)
	$(PY) -m pip install -q --disable-pip-version-check --no-deps --no-build-isolation -e .
	$(PY) -m inspector_tools.precompile
	@touch $(STAMP)

setup: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/inspector demo --out out/demo

# Two workers on this project's 2-core machine (at most 4 elsewhere), whole files per worker so
# that module fixtures (clusters, servers, captures) are made once. A worker that dies ends the
# run at once, named (a replaced worker left pytest-xdist waiting until CI's time ran out).
test: $(STAMP)
	$(VENV)/bin/pytest -q -n auto --maxprocesses=4 --dist loadfile --max-worker-restart=0

# The manual (mkdocs.yml): docs/ and the README as its home page, into out/site/; warnings are errors.
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet

clean:
	rm -rf $(VENV) out .pytest_cache

# Accuracy on captures written by another program (tests/acceptance/foreign_capture.py):
# unseen parts x imaging conditions through `inspector run`, table in docs/acceptance.md.
.PHONY: acceptance
acceptance: $(STAMP)
	$(PY) tests/acceptance/run_matrix.py --work out/acceptance --out-md docs/acceptance.md

# Pose sweep (issue 14): near-symmetric parts x scale errors x random poses x rigs of 16, 12
# and 8 cameras, summary per part and rig between markers in docs/acceptance.md. Resumable:
# captures are cached, and inspections and measurements of an unchanged product are reused
# (--resume), so an interrupted run continues. Override any POSE_* variable for a subset, e.g.
#   make pose-sweep POSE_PARTS=flange POSE_SCALES=1.00 POSE_POSES=1 POSE_CAMERAS=8
POSE_PARTS   ?= flange hub keyshaft flatshaft gear disc5
POSE_SCALES  ?= 0.97 0.98 1.00 1.02
POSE_POSES   ?= 3
POSE_CAMERAS ?= 16 12 8
POSE_JOBS    ?= 1
POSE_BATCH   ?= 4
POSE_WORK    ?= out/pose_sweep
POSE_MD      ?= docs/acceptance.md
.PHONY: pose-sweep acceptance-pose
pose-sweep: $(STAMP)
	$(PY) tests/acceptance/pose_sweep.py --parts $(POSE_PARTS) --scales $(POSE_SCALES) --poses $(POSE_POSES) \
		--cameras $(POSE_CAMERAS) --jobs $(POSE_JOBS) --batch $(POSE_BATCH) --work $(POSE_WORK) --resume \
		--md-section $(POSE_MD)
acceptance-pose: pose-sweep
