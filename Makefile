# Set-up is two commands: `make demo` and `make test`; both create the virtual environment.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-slow venv bytecode bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	@echo "make: installing dgcal and its dependencies into $(VENV) (1-3 min the first time) ..."
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install --progress-bar off -e '.[test]'
	$(BIN)/python -m dgcal.precompile
	touch $(STAMP)

# dgcal's bytecode, written once here: with PYTHONDONTWRITEBYTECODE set (as in many containers) every dgcal
# process would otherwise compile every module it imports (0.5 s per process); only changed files are redone
SOURCES := calib bundle pos fields sim reports dgcal

venv: $(STAMP)

bytecode: $(STAMP)
	$(BIN)/python -m compileall -q -j 0 $(SOURCES) > /dev/null

demo: bytecode
	$(BIN)/dgcal demo --out demo_out

test: bytecode
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist loadfile

# the long acceptance runs (marker `slow`), which CI runs after `make test`
test-slow: bytecode
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist loadfile -m slow

bench: bytecode
	for f in bench/*.py; do $(BIN)/python $$f; done

clean:
	rm -rf $(VENV) demo_out build *.egg-info
