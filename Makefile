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

DEMO := reports/demo
CLI := $(BIN)/iiwa-ident

# The main job on the default simulated joint: chirp -> fit -> constant velocity -> ripple -> design -> deploy.
demo: $(STAMP)
	@mkdir -p $(DEMO)
	$(CLI) chirp --target sim --duration 30 --seed 1 --out $(DEMO)/chirp.h5
	$(CLI) fit $(DEMO)/chirp.h5 --out $(DEMO)/model.toml --json $(DEMO)/fit.json --figures $(DEMO)/figures
	$(CLI) simulate constant_velocity --velocity 0.3,0.6,1.2 --seed 2 --out $(DEMO)/constant_velocity.h5
	$(CLI) ripple $(DEMO)/constant_velocity.h5 --model $(DEMO)/model.toml --out $(DEMO)/model_ripple.toml \
		--json $(DEMO)/ripple.json --figures $(DEMO)/figures
	$(CLI) design --model $(DEMO)/model_ripple.toml --out $(DEMO)/design.toml --json $(DEMO)/design.json
	$(CLI) deploy --design $(DEMO)/design.toml --out $(DEMO)/controller.toml --json $(DEMO)/controller.json
	@echo "outputs in $(DEMO): chirp.h5, model.toml, constant_velocity.h5, model_ripple.toml, design.toml,"
	@echo "  controller.toml, *.json and figures/*.png (inspect a dataset with: $(CLI) info $(DEMO)/chirp.h5)"

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python bench/bench_sim.py
	$(BIN)/python bench/bench_fri_codec.py
	$(BIN)/python bench/bench_logwriter.py
	$(BIN)/python bench/bench_fri_runtime.py 60
	$(BIN)/python bench/bench_diagnose.py

clean:
	rm -rf $(VENV) build *.egg-info
