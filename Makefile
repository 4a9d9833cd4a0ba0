LINT_PATHS = sb3_icrl/ tests/ benchmarks/ examples/

.PHONY: format check-codestyle lint type test pytest commit-checks

format:
	ruff check --select I --fix $(LINT_PATHS)
	black $(LINT_PATHS)

check-codestyle:
	ruff check --select I $(LINT_PATHS)
	black --check $(LINT_PATHS)

lint:
	ruff check $(LINT_PATHS)

type:
	mypy sb3_icrl/

pytest test:
	python -m pytest -n 2 tests/

commit-checks: format type lint
