# The two commands of the README: `make run` starts the simulator, `make test` runs every test.
# Each installs what it needs (Rust components, npm packages, Debian's chromium and nats-server)
# by itself. `make lab` runs a local teaching lab: NATS, two simulated stations and a hub.

CARGO ?= cargo
# Extra arguments for the simulator, e.g. `make run ARGS="--addr 0.0.0.0:8080 --scene scenes/cone.toml"`.
ARGS ?=
# Ports of `make lab`: NATS, the two stations, the hub.
LAB_NATS_PORT ?= 4222
LAB_PORTS ?= 8081 8082
LAB_HUB_PORT ?= 8090

.PHONY: run test lint test-rust test-web rust-tools web-deps chromium nats lab

run: rust-tools web-deps
	$(CARGO) run --release -p softhaptic-server --bin softhaptic -- $(ARGS)

test: lint test-rust test-web

lint: rust-tools web-deps
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets --all-features -- -D warnings
	# The crate docs map the code: a link to a moved or private item fails here, not in review.
	RUSTDOCFLAGS="-D warnings" $(CARGO) doc --workspace --no-deps --quiet
	cd web && npm run lint && npm run format:check

test-rust: rust-tools nats
	$(CARGO) test --workspace

test-web: web-deps chromium nats
	cd web && npm test
	cd web && npm run test:e2e

rust-tools:
	@command -v rustup >/dev/null 2>&1 && { rustup component list --installed | grep -q '^rustfmt' || rustup component add rustfmt; rustup component list --installed | grep -q '^clippy' || rustup component add clippy; } || true

# npm ci when node_modules is missing or older than the lock file.
web-deps:
	@if [ ! -d web/node_modules ] || [ web/package-lock.json -nt web/node_modules ]; then cd web && npm ci --no-audit --no-fund; fi

# Browser tests drive Debian's chromium through playwright-core (no browser download).
chromium:
	@command -v chromium >/dev/null 2>&1 || { \
	  echo "installing Debian's chromium for the browser tests"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y chromium; }

# The lab's tests run a real nats-server: Debian's package.
nats:
	@command -v nats-server >/dev/null 2>&1 || [ -x /usr/sbin/nats-server ] || { \
	  echo "installing Debian's nats-server for the lab's tests"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y nats-server; }

# A local teaching lab: nats-server with JetStream, two simulated stations (the liver pressed by
# a sphere and by a cone) and a hub; Ctrl-C stops them all.
lab: rust-tools web-deps nats
	$(CARGO) build --release -p softhaptic-server --bin softhaptic
	@dir=$$(mktemp -d); nats=$$(command -v nats-server || echo /usr/sbin/nats-server); \
	trap 'kill $$(jobs -p) 2>/dev/null; rm -rf "$$dir"' EXIT INT TERM; \
	$$nats -a 127.0.0.1 -p $(LAB_NATS_PORT) -js -sd "$$dir" & \
	sleep 1; set -- $(LAB_PORTS); \
	target/release/softhaptic --no-record --addr 127.0.0.1:$$1 --nats nats://127.0.0.1:$(LAB_NATS_PORT) --station desk-1 & \
	target/release/softhaptic --no-record --addr 127.0.0.1:$$2 --nats nats://127.0.0.1:$(LAB_NATS_PORT) --station desk-2 --scene scenes/cone.toml & \
	target/release/softhaptic hub --nats nats://127.0.0.1:$(LAB_NATS_PORT) --addr 127.0.0.1:$(LAB_HUB_PORT) & \
	wait
