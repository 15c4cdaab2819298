# The README's two commands: `make demo` and `make test`. Each creates .venv by itself.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
BINTRACK := $(VENV)/bin/bintrack
STAMP  := $(VENV)/.installed

.PHONY: demo demo-mqtt test test-fast test-engine datasets clean bench bench-multi browser mosquitto engine

PIP := $(PY) -m pip install -qq --disable-pip-version-check

# Quiet: a first run prints one line here, then the command's own output (pip's errors still show).
$(STAMP): pyproject.toml
	@echo "make: installing bintrack and its dependencies into $(VENV) (first run only)"
	@$(PYTHON) -m venv $(VENV)
	@$(PIP) --upgrade pip
	@$(PIP) -e '.[test]'
	@touch $(STAMP)

DEMO_ARGS ?=
demo: $(STAMP)
	@$(BINTRACK) demo $(DEMO_ARGS)

# One worker per core (pytest-xdist), a test file per worker: the live tests mostly wait on
# services and routers, so two files at once on 2 cores halve the time.
# The compose files run in podman too (tests/test_compose_engine.py, scheduled first as the
# longest file: about 5 min on a warm cache, 12 from an empty one, beside the other files).
test: $(STAMP) browser mosquitto engine
	BINTRACK_ENGINE_TESTS=1 $(PY) -m pytest -q -n auto --dist loadfile --no-loadscope-reorder

# The compose files in a real container engine (podman) alone: builds a Debian base and the
# image (cached by content hash) and runs the three files.
test-engine: $(STAMP) engine
	BINTRACK_ENGINE_TESTS=1 $(PY) -m pytest -q tests/test_compose_engine.py

# The inner loop (about a third of `make test`'s time): what `make test` runs but the `slow`
# tests (long or statistical checks) and the longest live files, which `make test` (and CI)
# still run: live equals offline for every tracker, kills and restarts of whole stacks, bad
# input to each service, regions on a router mesh and on hosts of their own, the two-site compose stack, lossy links.
FAST_SKIP := test_live.py test_faults.py test_bus_faults.py test_regions_live.py test_compose_multi.py \
             test_lossy_link.py test_compose_engine.py test_fault_pairs.py test_fault_peers.py test_fault_routers.py \
             test_hosts.py
test-fast: $(STAMP)
	$(PY) -m pytest -q -n auto --dist loadfile -m "not slow" $(addprefix --ignore=tests/,$(FAST_SKIP))

# The map's browser tests drive Debian's chromium-headless-shell (Playwright never downloads a
# browser). Installed here with apt-get when missing and apt-get is usable (root); elsewhere
# those tests are skipped with one line naming the package.
BROWSER_PACKAGE := chromium-headless-shell
browser:
	@if ! command -v chromium-headless-shell >/dev/null 2>&1 && ! command -v chromium >/dev/null 2>&1; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(BROWSER_PACKAGE)) >/dev/null \
	      || echo "make: could not install $(BROWSER_PACKAGE); the browser tests will be skipped"; \
	  else \
	    echo "make: $(BROWSER_PACKAGE) is not installed (apt-get install $(BROWSER_PACKAGE)); the browser tests will be skipped"; \
	  fi; \
	fi

# The MQTT tests (tests/test_mqtt_live.py), `make demo-mqtt` and benchmarks/mqtt_bridge.py run
# Debian's mosquitto broker on loopback; installed as the browser is, else those tests are skipped.
MQTT_PACKAGE := mosquitto
MOSQUITTO := $(shell command -v mosquitto 2>/dev/null || ls /usr/sbin/mosquitto 2>/dev/null)
mosquitto:
	@if [ -z "$(MOSQUITTO)" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(MQTT_PACKAGE)) >/dev/null \
	      || echo "make: could not install $(MQTT_PACKAGE); the MQTT tests will be skipped"; \
	  else \
	    echo "make: $(MQTT_PACKAGE) is not installed (apt-get install $(MQTT_PACKAGE)); the MQTT tests will be skipped"; \
	  fi; \
	fi

# tests/test_compose_engine.py builds the image on a Debian base made with mmdebstrap and runs
# the compose files in rootful podman (runtime runc): podman, podman-compose, mmdebstrap and runc
# are installed as the browser is (one `apt-get update`, one install), else those tests are skipped.
ENGINE_PACKAGES := podman podman-compose mmdebstrap runc
engine:
	@missing=""; for package in $(ENGINE_PACKAGES); do command -v $$package >/dev/null 2>&1 || missing="$$missing $$package"; done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -o DPkg::Lock::Timeout=600 -y -qq $$missing) >/dev/null \
	      || echo "make: could not install$$missing; the container engine tests will be skipped"; \
	  else \
	    echo "make:$$missing not installed (apt-get install$$missing); the container engine tests will be skipped"; \
	  fi; \
	fi

# Sensors on MQTT (README, "Real sensors on MQTT"): a mosquitto on 127.0.0.1:$(MQTT_PORT), the
# stack with the map reading it through the MQTT bridge, and darpa-grid-3 played in real time by
# simulated Zigbee2MQTT occupancy sensors. Ctrl-C stops everything.
MQTT_PORT ?= 1883
DEMO_MQTT := out/demo-mqtt
VIEW_PORT ?= 8080
demo-mqtt: $(STAMP) mosquitto
	@mkdir -p $(DEMO_MQTT) && rm -f $(DEMO_MQTT)/up.log
	@printf 'listener $(MQTT_PORT) 127.0.0.1\nallow_anonymous true\npersistence true\npersistence_location %s/\nmax_queued_messages 0\nlog_type error\nlog_type warning\n%s' \
	  "$$(pwd)/$(DEMO_MQTT)" "$$( [ "$$(id -u)" = 0 ] && echo 'user root' )" > $(DEMO_MQTT)/mosquitto.conf
	@$(BINTRACK) simulate darpa-grid --people 3 --seed 3 --out $(DEMO_MQTT)/dataset \
	  --sensor-table $(DEMO_MQTT)/sensor-table.toml --epoch 1970-01-01T00:00:00Z >/dev/null
	@trap 'kill $$broker $$stack 2>/dev/null; wait' EXIT INT TERM; \
	  $$(command -v mosquitto || echo /usr/sbin/mosquitto) -c $(DEMO_MQTT)/mosquitto.conf & broker=$$!; \
	  $(BINTRACK) up --source mqtt://127.0.0.1:$(MQTT_PORT) --sensor-table $(DEMO_MQTT)/sensor-table.toml \
	    --tracker mcmcda --map-port $(VIEW_PORT) $(UP_ARGS) 2> $(DEMO_MQTT)/up.log & stack=$$!; \
	  tail -n +1 -f --pid=$$stack $(DEMO_MQTT)/up.log >&2 & \
	  until grep -q "mqtt_bridge: subscribing" $(DEMO_MQTT)/up.log 2>/dev/null; do \
	    kill -0 $$stack 2>/dev/null || exit 1; sleep 0.5; done; \
	  $(BINTRACK) simulate darpa-grid --people 3 --seed 3 --out $(DEMO_MQTT)/dataset --publish mqtt://127.0.0.1:$(MQTT_PORT); \
	  echo "make: the devices are done; the stack keeps running (Ctrl-C to stop)"; wait $$stack

# Our MCMCDA against Stone Soup's GNN and JPDA (issue 6): needs the optional extra `bench`
# (Stone Soup), which only this target installs. 3–6 min on 2 cores; `make bench BENCH_ARGS=--quick`
# tries one Stone Soup setting instead of tuning (about 1 min).
BENCH_STAMP := $(VENV)/.installed-bench
BENCH_ARGS ?=

$(BENCH_STAMP): $(STAMP) pyproject.toml
	@$(PIP) -e '.[test,bench]'
	@touch $(BENCH_STAMP)

bench: $(BENCH_STAMP)
	$(PY) benchmarks/mcmcda_vs_stonesoup.py $(BENCH_ARGS)

# Issues 21 and 42: our MCMCDA against Stone Soup's GNN, JPDA, JIPDA, MFA and GM-PHD, tuned on half
# of a suite of simulated grids and scored on the other half (benchmarks/multi_target.py;
# `BENCH_ARGS=--quick` for a smaller run, `BENCH_ARGS="--conditions 3"` adds the harder conditions).
bench-multi: $(BENCH_STAMP)
	nice -n 10 $(PY) benchmarks/multi_target.py $(BENCH_ARGS)

# Remakes every shipped dataset byte for byte (seeds fixed).
datasets: $(STAMP)
	$(BINTRACK) simulate darpa-grid --people 1 --seed 1 --out datasets/darpa-grid-1
	$(BINTRACK) simulate darpa-grid --people 2 --seed 2 --out datasets/darpa-grid-2
	$(BINTRACK) simulate darpa-grid --people 3 --seed 3 --out datasets/darpa-grid-3
	$(BINTRACK) simulate darpa-grid --people 3 --seed 3 --regions 2x1 --out datasets/darpa-grid-3-sites
	$(BINTRACK) simulate laser-testbed --seed 1 --out datasets/laser-testbed

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis out
