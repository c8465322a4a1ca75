# One-command entry points for a fresh machine (Python >= 3.11 on PATH).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
OUT ?= out/scenario1

.PHONY: install run mc test bench clean

$(BIN)/uavsearch: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $@

install: $(BIN)/uavsearch

# The main job: a full simulated mission (simulator + one companion per UAV), sped up 10x.
run: install
	$(BIN)/uavsearch run mission_files/scenario1.toml --speedup 10 --steps 300 --out $(OUT)

# The paper's Monte Carlo comparison on scenario 1 (summary table and plots).
mc: install
	$(BIN)/uavsearch mc --mission mission_files/scenario1.toml \
		--algorithms proposed,no-ta,pheromone --runs 20 --steps 1000 --seed 1 --out out/mc/scenario1

test: install
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q

bench: install
	$(BIN)/uavsearch bench

clean:
	rm -rf $(VENV) out .pytest_cache
