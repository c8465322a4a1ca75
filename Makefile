# One-command entry points for a fresh machine (Python >= 3.11 on PATH).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
OUT ?= out/scenario1

.PHONY: install run test lint bench clean

$(BIN)/uavsearch: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $@

install: $(BIN)/uavsearch

run: install
	$(BIN)/uavsearch mc --mission mission_files/scenario1.toml \
		--algorithms proposed,no-ta,pheromone --runs 20 --steps 1000 --seed 1 --out $(OUT)

test: install
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q

bench: install
	$(BIN)/uavsearch bench

clean:
	rm -rf $(VENV) out .pytest_cache
