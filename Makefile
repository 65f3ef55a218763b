# The commands: `make demo`, `make check` (the fast tier, for a contributor every few minutes),
# `make test` (every test but the long runs, what CI runs) and `make long` (the long runs: tests of
# 4 s or more). Each creates .venv when missing.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.bgc-installed
#: The markers `make check` leaves out (pyproject.toml says what each means).
FULL_ONLY := slow or process or numba or install or browser or long
#: The long runs (tests of 4 s or more: seeded statistics, memory peaks, long streams, campaigns, the
#: slower end-to-end scenarios): `make long` runs them, with a table of their times, and `make test`
#: does not (long runs are benchmarks).
LONG := long
#: Test processes (pytest-xdist; a test file stays on one): one per core of the 2-core machine (three
#: were slower, measured); `make test TEST_JOBS=0` runs in this one.
TEST_JOBS ?= 2
#: One BLAS thread per test process: the two processes fill the two cores, and OpenBLAS's own threads
#: beside them only contend (measured: 5 to 9 % off the wall time of three test files each way).
PYTEST := OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MPLBACKEND=Agg $(BIN)/python -m pytest -n $(TEST_JOBS) --dist loadfile

.PHONY: demo check test long clean

# Print a CSV's lines one at a time, a pause between rows: a plant's logger, for the monitor.
define REPLAY
import sys, time
pause = float(sys.argv[2])
for line in open(sys.argv[1]):
    sys.stdout.write(line)
    sys.stdout.flush()
    if line[:1].isdigit():
        time.sleep(pause)
endef
export REPLAY

# The installed modules' bytecode is written once, at install: where PYTHONDONTWRITEBYTECODE is set
# (this machine) nothing else would, and every process of the tests would compile its imports from
# source (measured: the suite 608 s -> 753 s without it). pip would write it one file at a time (half
# of the install's 46 s); compileall -j 0 writes the same files on every core (21 s + 13 s, measured).
# bgc itself is built with the environment's own setuptools and wheel (pyproject.toml's build
# requirement, installed first), not in an isolated build environment pip would make afresh each
# time (measured: the install 42 s -> 32 s).
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --no-compile --disable-pip-version-check 'setuptools>=64' wheel
	$(BIN)/python -m pip install --quiet --no-compile --disable-pip-version-check --no-build-isolation -e '.[test]'
	$(BIN)/python -m compileall -q -j 0 $$($(BIN)/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])') > /dev/null
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/bgc check models/circuit.yaml models/two_tank.yaml models/ro.yaml
	$(BIN)/bgc compile models/ro.yaml -o out/generated
	$(BIN)/bgc show equations models/ro.yaml
	$(BIN)/bgc show dbn models/ro.yaml --fault R_pipe:incipient --format png -o out/ro-dbn-R_pipe_incipient.png
	$(BIN)/bgc simulate models/ro.yaml --steps 300 --fault R_pipe:incipient:0.5@165 --noise process=0.03,measurement=0.02 --seed 1 -o out/ro-run.csv --plot out/ro-run.png
	$(BIN)/bgc filter models/ro.yaml out/ro-run.csv --generated out/generated --plot out/ro-nominal-filter.png
	$(BIN)/bgc filter models/ro.yaml out/ro-run.csv --generated out/generated --fault R_pipe:incipient --start 167 --plot out/ro-R_pipe-incipient-filter.png
	$(BIN)/bgc diagnose models/ro.yaml --data out/ro-run.csv --noise process=0.03,measurement=0.02 --generated out/generated -o out/diagnosis
	@echo "demo: the same run as a stream, row by row through a pipe, into bgc monitor (events as they arrive):"
	$(BIN)/python -c "$$REPLAY" out/ro-run.csv 0.01 | $(BIN)/bgc monitor models/ro.yaml --data - --noise process=0.03,measurement=0.02 --generated out/generated -o out/monitor
	@echo "demo: the RO cycling through its three valve settings twice (the valve in the data's mode column), its pipe clogging from t = 140 in the second cycle, monitored through its switches:"
	$(BIN)/bgc simulate models/ro_hybrid_valve.yaml --steps 300 --modes secondary@60,purge@100,primary@120,secondary@180,purge@220,primary@240 --fault R_pipe:incipient:0.5@140 --seed 4 -o out/ro-cycles.csv --plot out/ro-cycles.png
	$(BIN)/python -c "$$REPLAY" out/ro-cycles.csv 0.01 | $(BIN)/bgc monitor models/ro_hybrid_valve.yaml --data - -o out/ro-cycles-monitor
	@echo "demo: pictures and data in out/; the diagnosis report is out/diagnosis/report.md (plots beside it; open out/diagnosis/report.html in a browser: the same in one page), the monitors' out/monitor/ and out/ro-cycles-monitor/ (report.md, report.html)"

# The bytecode of bgc and of the committed packages, written once before the tests (gitignored
# __pycache__ folders): where PYTHONDONTWRITEBYTECODE is set (this machine), every fresh process of
# the tests would otherwise compile them from source again.
BYTECODE := $(BIN)/python -m compileall -q bgc generated tests > /dev/null

check: $(STAMP)
	$(BYTECODE)
	$(PYTEST) -m "not ($(FULL_ONLY))"

test: $(STAMP)
	$(BYTECODE)
	$(PYTEST) -m "not $(LONG)"

long: $(STAMP)
	$(BYTECODE)
	$(PYTEST) -m "$(LONG)" --durations=0

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis "$${XDG_CACHE_HOME:-$$HOME/.cache}/bgc-tests"
