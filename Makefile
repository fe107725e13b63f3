# pipeline-sim: the two commands a fresh machine needs are `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
BENCH_STAMP := $(VENV)/.installed-bench

.PHONY: demo test bench report docs warmup clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[test]'
	touch $(STAMP)

## demo: set up, then simulate the default motion blur + depth of field workload into runs/default
demo: $(STAMP)
	$(VENV)/bin/pipeline-sim run workloads/scenes/default.toml --out runs/default
	@echo "image: runs/default/passes/main/image.png  counters: runs/default/passes/main/counters.csv  report: runs/default/report.html"

## test: set up, then run the test suite
test: $(STAMP)
	$(PY) -m pytest -q

# the benchmarks' optional peer (Mesa llvmpipe through moderngl); the bench runs without it if it cannot install
$(BENCH_STAMP): $(STAMP)
	$(PY) -m pip install --quiet -e '.[test,bench]' || echo "moderngl not installed: the llvmpipe peer is skipped"
	touch $(BENCH_STAMP)

## bench: set up, then run the benchmarks (table printed, results saved in bench-results/)
bench: $(BENCH_STAMP)
	$(PY) -m benchmarks.run --out bench-results

## report: set up, then run the shipped study "what accuracy costs" and write its report
report: $(STAMP)
	$(VENV)/bin/pipeline-sim sweep workloads/sweeps/accuracy_cost.toml --out runs/accuracy_cost
	$(VENV)/bin/pipeline-sim report runs/accuracy_cost -o runs/accuracy_cost/report.html

## docs: regenerate the settings tables and the counter glossary in docs/ from the code's declarations
docs: $(STAMP)
	$(PY) -m pipeline_sim.docgen

warmup: $(STAMP)
	$(VENV)/bin/pipeline-sim warmup

clean:
	rm -rf runs bench-results .pytest_cache .hypothesis
	find . -name __pycache__ -prune -exec rm -rf {} +
