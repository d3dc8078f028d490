# Set-up and checks. `make demo` and `make test` are all a fresh machine needs.
# The first Python 3.11 or newer on PATH (or PYTHON=/path/to/python).
PYTHON ?= $(shell for p in python3.11 python3.12 python3.13 python3.14 python3; do \
	command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null \
	&& { echo $$p; break; }; done)
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-realtime bench clean proto

$(STAMP): pyproject.toml
	@test -n "$(PYTHON)" && command -v $(PYTHON) >/dev/null 2>&1 || { echo "need Python 3.11 or newer on PATH (or PYTHON=...)"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	@touch $(STAMP)

DEMO := reports/demo
CLI := $(BIN)/iiwa-ident

# The whole pipeline on the default simulated joint: experiments, fit, ripple, design, deploy, the closed loop
# through the FRI runtime against the emulator with the live kappa sweeps, diagnosis, and the PDF report
# (about 115 s after the install).
demo: $(STAMP)
	@mkdir -p reports
	$(CLI) pipeline --target sim --workdir $(DEMO); status=$$?; cp $(DEMO)/report.pdf reports/demo.pdf; exit $$status
	@echo "report: reports/demo.pdf; every intermediate file in $(DEMO)/ (pipeline.json lists them)"

# The linter and the type checker first (their rules in pyproject.toml), then two workers, one test file each at a time (module
# fixtures are built once); nothing in it depends on wall-clock timing. The few tests that must run in real time are marked `realtime` and run apart.
# One BLAS thread per worker: two workers with a BLAS thread pool each oversubscribe the cores.
test: $(STAMP)
	$(BIN)/ruff check iiwa_ident tests bench
	$(BIN)/mypy
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist loadfile -m "not realtime" --durations=25

test-realtime: $(STAMP)
	$(BIN)/python -m pytest -q -m realtime

bench: $(STAMP) test-realtime
	$(BIN)/python bench/bench_sim.py
	$(BIN)/python bench/bench_fri_codec.py
	$(BIN)/python bench/bench_logwriter.py
	$(BIN)/python bench/bench_fri_runtime.py 60
	$(BIN)/python bench/bench_diagnose.py
	$(BIN)/python bench/bench_pipeline.py

clean:
	rm -rf $(VENV) build *.egg-info

# Regenerate the FRI messages' Python module after an edit of their schema. Only this target needs protoc
# (from grpcio-tools, in a throw-away environment); installing and running the package do not.
proto:
	$(PYTHON) -m venv /tmp/iiwa-ident-protoc
	/tmp/iiwa-ident-protoc/bin/pip install --quiet 'grpcio-tools==1.85.1'
	/tmp/iiwa-ident-protoc/bin/python -m grpc_tools.protoc -I. --python_out=. --pyi_out=. iiwa_ident/fri/messages.proto
