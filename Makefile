# The two commands of the README: `make run` starts the simulator, `make test` runs every test.
# Each installs what it needs (Rust components, npm packages, Debian's chromium) by itself.

CARGO ?= cargo
# Extra arguments for the simulator, e.g. `make run ARGS="--addr 0.0.0.0:8080 --scene scenes/cone.toml"`.
ARGS ?=

.PHONY: run test lint test-rust test-web rust-tools web-deps chromium

run: rust-tools web-deps
	$(CARGO) run --release -p softhaptic-server --bin softhaptic -- $(ARGS)

test: lint test-rust test-web

lint: rust-tools web-deps
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets -- -D warnings
	cd web && npm run lint && npm run format:check

test-rust: rust-tools
	$(CARGO) test --workspace

test-web: web-deps chromium
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
