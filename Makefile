# make demo | test | bench | lint   (each installs into .venv first if needed)
VENV ?= .venv
PYTHON ?= python3
STAMP := $(VENV)/.installed-stamp

.PHONY: install demo test test-slow bench bench-scale bench-quality lint clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(VENV)/bin/recon demo

test: install
	$(VENV)/bin/pytest -q

test-slow: install
	$(VENV)/bin/pytest -q -m slow

bench: install
	$(VENV)/bin/python -m recon.bench

bench-scale: install
	$(VENV)/bin/python -m recon.bench --only scale

bench-quality: install
	$(VENV)/bin/python -m recon.bench --only quality

lint: install
	$(VENV)/bin/ruff check recon tests

clean:
	rm -rf demo_workspace demo_scene bench_out
