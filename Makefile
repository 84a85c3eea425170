# AMazING mobile-node manager. `make run` starts everything locally; `make test` proves it.
SHELL := /bin/bash
.DEFAULT_GOAL := help

PYTHON_BOOT ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMPS := .make
ASSETS := var/assets

# Test services: real PostgreSQL and Redis on this machine (see tests/ensure_services.sh).
TEST_DATABASE_URL ?= postgres://postgres@127.0.0.1:5432/amazing
TEST_REDIS_URL ?= redis://127.0.0.1:6379/14
TEST_ENV := DJANGO_DEBUG=1 AMAZING_TEST_REQUIRE_POSTGRES=1 DATABASE_URL=$(TEST_DATABASE_URL) REDIS_URL=$(TEST_REDIS_URL) \
	CELERY_BROKER_URL=$(TEST_REDIS_URL)

.PHONY: help setup run test ci lint audit format bench soak screenshots firmware cad clean system-deps services

help:
	@echo "make run    - set up and start the whole system locally (simulated robot)"
	@echo "make test   - set up and run every test suite against PostgreSQL and Redis"
	@echo "make lint   - ruff, mypy, the pages' scripts type-checked, import layers, compose validation, dependency audit"
	@echo "make audit  - known vulnerabilities in the Python and npm packages"
	@echo "make bench  - benchmarks (results go to docs/performance.md)"
	@echo "make soak   - the whole system under random faults for SOAK_MINUTES (30), checked (docs/reliability.md)"
	@echo "make screenshots - every page of a whole running system, at a laptop's and a phone's width, into docs/screenshots"
	@echo "make firmware - cross-compile the robot firmware"
	@echo "make cad   - build the 3D models (STEP, STL) into var/cad and refresh docs/cad"
	@echo "make clean  - remove the virtualenv, assets and local data"

$(STAMPS):
	@mkdir -p $(STAMPS)

# Python packages: reinstalled when pyproject.toml changes. uv installs the same pinned
# packages as pip would, in a third of pip's CPU time (on a fresh checkout this step stands
# before everything else). Compiled to bytecode as pip does: where PYTHONDONTWRITEBYTECODE is
# set, nothing else ever writes it, and every process of the system (a test starts hundreds)
# would compile Django and the rest from source, four seconds of CPU each.
UV_VERSION := 0.13.9
$(STAMPS)/venv: pyproject.toml | $(STAMPS)
	@test -x $(PY) || $(PYTHON_BOOT) -m venv $(VENV)
	$(PY) -m pip install --quiet uv==$(UV_VERSION)
	$(VENV)/bin/uv pip install --quiet --compile-bytecode --python $(PY) -e '.[portal,basestation,cli,dev,cad]'
	@touch $@

# Front-end packages from npm, copied to where Django's staticfiles finds them; the development
# ones too (TypeScript, which `make lint` checks the pages' scripts with), whatever NODE_ENV says.
$(STAMPS)/assets: package.json package-lock.json | $(STAMPS)
	npm ci --include=dev --no-audit --no-fund --loglevel=error
	rm -rf $(ASSETS)/vendor
	mkdir -p $(ASSETS)/vendor/pico $(ASSETS)/vendor/chart.js $(ASSETS)/vendor/swagger-ui-dist \
		$(ASSETS)/vendor/luxon $(ASSETS)/vendor/event-calendar \
		$(ASSETS)/vendor/js-yaml
	cp node_modules/@picocss/pico/css/pico.min.css $(ASSETS)/vendor/pico/
	cp node_modules/chart.js/dist/chart.umd.js $(ASSETS)/vendor/chart.js/
	cp node_modules/luxon/build/global/luxon.min.js $(ASSETS)/vendor/luxon/
	# Event Calendar (core, time grid, day grid, list, resource timeline, interaction) as its
	# project builds it for browsers: the calendar page and the timeline.
	cp node_modules/@event-calendar/build/dist/event-calendar.min.{js,css} $(ASSETS)/vendor/event-calendar/
	cp node_modules/js-yaml/dist/browser/js-yaml.umd.min.js $(ASSETS)/vendor/js-yaml/
	cp node_modules/swagger-ui-dist/{swagger-ui-bundle.js,swagger-ui-standalone-preset.js,swagger-ui.css,favicon-32x32.png} \
		$(ASSETS)/vendor/swagger-ui-dist/
	@touch $@

# Debian packages the tests need: Chromium for browser tests, docker-compose to validate the
# compose file, the AVR toolchain and Arduino core for the firmware.
APT_NEEDS := /usr/bin/chromium:chromium /usr/bin/docker-compose:docker-compose \
	/usr/bin/avr-gcc:gcc-avr /usr/share/arduino/Arduino.mk:arduino-mk \
	/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h:arduino-core-avr \
	/usr/lib/avr/include/avr/io.h:avr-libc /usr/include/simavr/sim_avr.h:libsimavr-dev
system-deps:
	@missing=""; for need in $(APT_NEEDS); do \
		test -e "$${need%%:*}" || missing="$$missing $${need##*:}"; done; \
	if [ -n "$$missing" ]; then \
		echo "installing Debian packages:$$missing"; \
		if [ "$$(id -u)" != 0 ]; then echo "need root to install:$$missing" >&2; exit 1; fi; \
		DEBIAN_FRONTEND=noninteractive apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi

# The project's own modules compiled too, for the same reason (only what changed since).
SOURCES := core portal bookings basestation amazing_cli cad bench deploy tests manage.py
setup: $(STAMPS)/venv $(STAMPS)/assets
	@$(PY) -m compileall -q -j 0 $(SOURCES)

# nginx, the compose file's proxy, for the tests that put deploy/nginx.conf in front of the web
# server (tests/security/test_behind_nginx.py): Debian's binary unpacked under var/, never
# installed as a service (its package's scripts would start one on port 80).
NGINX := var/tools/nginx/usr/sbin/nginx
$(NGINX):
	@rm -rf var/tools/nginx var/tools/nginx-deb && mkdir -p var/tools/nginx-deb
	cd var/tools/nginx-deb && apt-get download -qq nginx 2>&1 | grep -v "^W: Download is performed unsandboxed" || true
	dpkg-deb -x var/tools/nginx-deb/nginx_*.deb var/tools/nginx
	@$(NGINX) -v

run: setup
	$(PY) -m portal.launcher

services:
	@bash tests/ensure_services.sh $(TEST_DATABASE_URL) $(TEST_REDIS_URL)

# Firmware first (seconds; the simulator's library too, before any agent starts), then every
# Python suite; pytest's summary closes the output.
test: setup system-deps services $(NGINX)
	$(MAKE) --no-print-directory -C firmware test shared hex size-check avrsim
	$(TEST_ENV) $(PY) -m pytest

# Known vulnerabilities in the installed Python and npm packages (deploy/audit_dependencies.py,
# accepted advisories in deploy/audit-allowlist.toml). An audit that cannot reach the advisory
# services fails too, unless AUDIT_INCOMPLETE=warn.
AUDIT_INCOMPLETE ?= fail
audit: setup
	$(PY) deploy/audit_dependencies.py --incomplete=$(AUDIT_INCOMPLETE)

# tsc: the pages' scripts, plain JavaScript, type-checked (portal/web/jsconfig.json).
lint: setup system-deps
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	DJANGO_DEBUG=1 $(VENV)/bin/mypy core portal bookings basestation amazing_cli cad bench deploy/audit_dependencies.py
	node_modules/.bin/tsc -p portal/web/jsconfig.json
	$(VENV)/bin/lint-imports --no-cache
	docker-compose -f docker-compose.yml config --quiet
	DJANGO_DEBUG=1 $(PY) manage.py makemigrations --check --dry-run
	DJANGO_DEBUG=1 $(PY) -W error manage.py spectacular --validate --fail-on-warn --file /dev/null
	$(MAKE) --no-print-directory audit

format: setup
	$(VENV)/bin/ruff check --fix .
	$(VENV)/bin/ruff format .

# The lint runs beside the tests, not before them: the tests' first minutes are mostly real
# processes waiting on real time, which the lint's CPU fills (about a minute less on a 2-core
# machine). Its output follows pytest's; the run fails if either failed.
ci: setup system-deps services $(NGINX)
	@mkdir -p var; \
	$(MAKE) --no-print-directory lint > var/lint.log 2>&1 & lint=$$!; \
	$(MAKE) --no-print-directory test; tests=$$?; \
	wait $$lint; linted=$$?; \
	echo "---- make lint, run beside the tests ----"; cat var/lint.log; \
	echo "ci: make test exit $$tests, make lint exit $$linted"; \
	[ $$tests -eq 0 ] && [ $$linted -eq 0 ]

firmware: system-deps
	$(MAKE) --no-print-directory -C firmware hex size-check

cad: $(STAMPS)/venv
	$(PY) -m cad build --out var/cad --svg-dir docs/cad

bench: setup services
	$(TEST_ENV) $(PY) -m bench

# Its own PostgreSQL cluster and redis-server on free ports; the report goes to
# docs/reliability.md. SOAK_SEED picks another sequence of faults.
SOAK_MINUTES ?= 30
soak: setup services
	$(TEST_ENV) SOAK_MINUTES=$(SOAK_MINUTES) $(PY) -m bench.soak --report

# The accessibility test photographs every page at both widths as it checks it.
screenshots: setup system-deps services
	$(TEST_ENV) SCREENSHOT_DIR=docs/screenshots $(PY) -m pytest tests/browser/test_accessibility.py \
		tests/browser/test_measurements.py -q

clean:
	rm -rf $(VENV) $(STAMPS) node_modules var .mypy_cache .ruff_cache .pytest_cache .hypothesis
	$(MAKE) -C firmware clean
