# One-command entry points for a fresh machine (Python >= 3.11 on PATH).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
OUT ?= out/scenario1
STUDY_RUNS ?= 1000
STUDY_OUT ?= out/study
SWEEP_RUNS ?= 50
SENSING_RUNS ?= 1000

.PHONY: install browser run run-nofly run-sitl run-px4 mc study sensing-study test bench clean

$(BIN)/uavsearch: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,cluster]'
	touch $@

install: $(BIN)/uavsearch

# The main job: a full simulated mission (simulator + one companion per UAV), sped up 10x.
run: install
	$(BIN)/uavsearch run mission_files/scenario1.toml --speedup 10 --steps 300 --out $(OUT)

# The same with a no-fly band across the region, the area from a QGroundControl plan
# (docs/mission-files.md, "The example mission").
run-nofly: install
	$(BIN)/uavsearch run mission_files/scenario1_nofly.toml --speedup 10 --steps 300 --out out/scenario1_nofly

# The same on real autopilots: one ArduPlane SITL per UAV (binary from $ARDUPLANE_SITL or
# ../shared/sitl/arduplane), sped up 4x (docs/companion.md, "Flying ArduPlane SITL").
run-sitl: install
	$(BIN)/uavsearch run mission_files/scenario1_continuous.toml --autopilot ardupilot-sitl --speedup 4 \
		--steps 300 --out out/scenario1_sitl

# The same on PX4: one PX4 SITL (SIH fixed-wing) per UAV (build from $PX4_SITL_DIR or ../shared/px4),
# sped up 2x, 150 steps: four SIH instances take more of two cores than ArduPlane's (docs/companion.md,
# "Flying PX4 SITL").
run-px4: install
	$(BIN)/uavsearch run mission_files/scenario1_px4.toml --autopilot px4-sitl --speedup 2 \
		--steps 150 --out out/scenario1_px4

# The paper's Monte Carlo comparison on scenario 1 (summary table and plots).
mc: install
	$(BIN)/uavsearch mc --mission mission_files/scenario1.toml \
		--algorithms proposed,no-ta,pheromone --runs 20 --steps 1000 --seed 1 --out out/mc/scenario1

# The paper's whole study (docs/results.md): 3 scenarios x 3 algorithms x 1,000 runs x 1,000 steps,
# then the n_g sweep; prints the wall time of the study. STUDY_RUNS=20 SWEEP_RUNS=5 make a quick one.
study: install
	@start=$$(date +%s); \
	for s in 1 2 3; do \
		$(BIN)/uavsearch mc --mission mission_files/scenario$$s.toml --algorithms proposed,no-ta,pheromone \
			--runs $(STUDY_RUNS) --steps 1000 --seed 1 --out $(STUDY_OUT)/scenario$$s || exit 1; \
	done; \
	echo "the whole study took $$(( $$(date +%s) - start )) s"
	$(BIN)/uavsearch sweep --mission mission_files/scenario2.toml --param n_g \
		--values 10,20,30,40,50,60,70,80,90 --runs $(SWEEP_RUNS) --steps 1000 --seed 1 --out $(STUDY_OUT)/sweep_n_g

# Imperfect sensing (docs/results.md, "Imperfect sensing"): 3 scenarios x Pd {1, 0.9, 0.7} x
# Pf {0, 0.01, 0.05} x 3 algorithms x SENSING_RUNS runs of 1,000 steps, paired. Cells are written as
# they finish; the same command again resumes. SENSING_RUNS=20 make sensing-study: a quick one.
sensing-study: install
	$(BIN)/uavsearch sensing-study --runs $(SENSING_RUNS) --steps 1000 --seed 1 \
		--out $(STUDY_OUT)/sensing_$(SENSING_RUNS)

# The view's browser tests drive Debian's Chromium (Playwright cannot download browsers here).
browser:
	@if [ ! -x /usr/bin/chromium ]; then \
		if [ "$$(id -u)" = 0 ]; then \
			apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; \
		else \
			echo "warning: /usr/bin/chromium is missing (as root: apt-get install chromium); the browser tests will be skipped"; \
		fi; \
	fi

test: install browser
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/mypy
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup --durations=25

bench: install
	$(BIN)/uavsearch bench

clean:
	rm -rf $(VENV) out .pytest_cache
