# Set-up and checks. `make demo` and `make test` are all a fresh machine needs.
PYTHON ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) on PATH"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	@touch $(STAMP)

demo: $(STAMP)
	$(BIN)/iiwa-ident chirp --target sim --duration 30 --seed 1 --out reports/demo/chirp.h5
	@echo "outputs: reports/demo/chirp.h5 (inspect with: $(BIN)/iiwa-ident info reports/demo/chirp.h5)"

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python bench/bench_sim.py

clean:
	rm -rf $(VENV) build *.egg-info
