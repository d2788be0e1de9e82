# bhem-hpc: every target installs what it needs first (Debian 12, root or sudo).
SYSTEM_PYTHON := /usr/bin/python3
VENV := .venv
PY := $(VENV)/bin/python
# One BLAS thread per MPI rank (see jobs/run.sh).
MPIRUN := OPENBLAS_NUM_THREADS=1 mpirun --allow-run-as-root --oversubscribe -x OPENBLAS_NUM_THREADS
RUFF_VERSION := 0.8.4
# ipc-toolkit, the incremental potential contact library (contact/ipc.py)
IPCTK_VERSION := 1.6.1
# McNeel's OpenNURBS for Rhino .3dm files (bhem_hpc/io/cad.py)
RHINO3DM_VERSION := 8.35.0
# numba: the compiled ray casting of the solids' setup (bhem_hpc/compiled); 0.58 is the last
# release that takes Debian's numpy 1.24 and Python 3.11
NUMBA_VERSION := 0.58.1
LLVMLITE_VERSION := 0.41.1
# pytest-xdist: the serial half of the suite on two worker processes (one per core)
XDIST_VERSION := 3.6.1
EXECNET_VERSION := 2.1.1
# The main job: a scene and its output directory (overwritten).
SCENE ?= jobs/drape.toml
OUT ?= out/demo

.PHONY: setup demo test test-serial test-mpi lint bench stress study docs scaling cloth clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml scripts/install-system-packages Makefile
	scripts/install-system-packages
	[ -x $(PY) ] || $(SYSTEM_PYTHON) -m venv --system-site-packages $(VENV)
	$(PY) -m pip install -q --no-build-isolation --no-deps -e .
	$(PY) -m pip install -q ruff==$(RUFF_VERSION) ipctk==$(IPCTK_VERSION) rhino3dm==$(RHINO3DM_VERSION)
	$(PY) -m pip install -q --no-deps numba==$(NUMBA_VERSION) llvmlite==$(LLVMLITE_VERSION)
	$(PY) -m bhem_hpc.compiled
	$(PY) -m pip install -q --no-deps execnet==$(EXECNET_VERSION) pytest-xdist==$(XDIST_VERSION)
	touch $@

demo: setup
	$(VENV)/bin/bhem-hpc run $(SCENE) --out $(OUT) --force

test: setup lint test-serial test-mpi

lint: setup
	$(VENV)/bin/ruff check bhem_hpc forms tests

# Serial tests on two worker processes, each taking the next test as it finishes one.
test-serial: setup
	$(PY) -m pytest -n 2 --dist worksteal

# Every rank runs the whole suite; rank 0 reports, the others write JUnit XML to out/.
test-mpi: setup
	mkdir -p out
	$(MPIRUN) -n 2 scripts/pytest-rank --color=no

bench: setup
	$(VENV)/bin/bhem-hpc bench --patches 10 20 30
	$(MPIRUN) -n 2 $(VENV)/bin/bhem-hpc bench --patches 10 20 30

# Long stability cases (720-degree twist, cylinder buckling, 10,000 steps) behind the `stress` marker.
# The serial run saves each case's final positions; the 2-rank run must reproduce them.
stress: setup
	rm -rf out/stress-serial
	$(PY) -m pytest -m stress --serial-results=out/stress-serial
	$(MPIRUN) -n 2 scripts/pytest-rank -m stress --color=no -s --serial-results=out/stress-serial

# Both linear solvers on the million-DoF cloth at three sizes, 1 and 2 ranks, weak scaling,
# Krylov iterations against dt and MUMPS factoring at every Newton iteration at 200 x 200:
# docs/scaling.md (about 45 minutes here).
scaling: setup
	$(VENV)/bin/bhem-hpc bench --scaling --patches 100 200 290 --ranks 1 2 --weak 100 --dt 0.001 0.002 0.004 0.008 \
		--fresh 200 --steps 4 --docs docs

# The cotton jobs (hanging, drape-cotton, shear, locking-cotton) at the B-spline cloth paper's
# resolutions, timed against its table: docs/cloth-comparison.md (hours on this machine).
cloth: setup
	$(VENV)/bin/bhem-hpc cloth --docs docs --out out/cloth

# Long studies run behind the `study` marker and assert their convergence claims.
study: setup
	$(PY) -m pytest -m study

# Every measured figure the project shows: docs/accuracy-cost.md (every study serially, then on
# 2 ranks, side by side), docs/performance.md (benchmarks, one run), and README.md's summary of both.
docs: setup
	$(VENV)/bin/bhem-hpc study --docs docs
	$(MPIRUN) -n 2 $(VENV)/bin/bhem-hpc study --docs docs
	$(VENV)/bin/bhem-hpc bench --docs docs
	$(VENV)/bin/bhem-hpc paths --docs docs
	OPENBLAS_NUM_THREADS=1 $(VENV)/bin/bhem-hpc solids --docs docs
	$(VENV)/bin/bhem-hpc summary --docs docs --readme README.md

clean:
	rm -rf $(VENV) out build *.egg-info
