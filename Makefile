# The two commands of the README: `make run` starts the simulator, `make test` runs every test.
# Each installs what it needs (Rust components, npm packages, Debian's chromium and nats-server)
# by itself. `make lab` runs a local teaching lab: NATS, two simulated stations and a hub.
# `make package` makes the Debian package (target/debian/softhaptic_*.deb; docs/install.md).

CARGO ?= cargo
# Extra arguments for the simulator, e.g. `make run ARGS="--addr 0.0.0.0:8080 --scene scenes/cone.toml"`.
ARGS ?=
# The cargo profile `make package` builds and packages. The tests package the test build's
# binary (dev) instead, the one the browser tests build with the same command (so CI compiles
# nothing more for it): a release build would cost CI several minutes; the package's layout and
# the files in it are the same.
PACKAGE_PROFILE ?= release
# The debug symbols go into a -dbgsym .ddeb beside the package; the tests' package strips them.
PACKAGE_DEB_FLAGS ?= --dbgsym
TARGET_DIR := $(or $(CARGO_TARGET_DIR),target)
PACKAGE_BUILD := $(TARGET_DIR)/$(if $(filter dev,$(PACKAGE_PROFILE)),debug,$(PACKAGE_PROFILE))
# How `make package` compiles the binary it packages.
PACKAGE_COMPILE ?= $(CARGO) build --profile $(PACKAGE_PROFILE) -p softhaptic-server --bin softhaptic
PACKAGE_GEN := $(PACKAGE_BUILD)/softhaptic-package
# Ports of `make lab`: NATS, the two stations, the hub.
LAB_NATS_PORT ?= 4222
LAB_PORTS ?= 8081 8082
LAB_HUB_PORT ?= 8090
# The cargo profile of `make lab`'s binary (`dev`: a debug build, no release build to wait for).
LAB_PROFILE ?= release
LAB_BUILD := $(TARGET_DIR)/$(if $(filter dev,$(LAB_PROFILE)),debug,$(LAB_PROFILE))

.PHONY: run test lint test-rust test-bin test-web test-package package cargo-deb rust-tools web-deps chromium nats lab

run: rust-tools web-deps
	$(CARGO) run --release -p softhaptic-server --bin softhaptic -- $(ARGS)

test: lint test-rust test-web test-package

lint: rust-tools web-deps
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets --all-features -- -D warnings
	# The crate docs map the code: a link to a moved or private item fails here, not in review.
	RUSTDOCFLAGS="-D warnings" $(CARGO) doc --workspace --no-deps --quiet
	cd web && npm run lint && npm run format:check

# The binary embeds the viewer and three.js (server/serve/build.rs stops without web/node_modules).
test-rust: rust-tools web-deps nats
	# Every feature, so the report commands' own tests (their command lines) run too.
	$(CARGO) test --workspace --all-features

# The browser and package tests run the binaries `cargo test --workspace --all-features` builds
# (the server's and the tests crate's own tests need them): a plain `cargo build` resolves
# features differently and would compile the device and server crates a second time.
TEST_BIN_DIR := $(abspath $(TARGET_DIR))/debug
TEST_BIN_BUILD := $(CARGO) test --workspace --all-features --no-run

test-bin: rust-tools web-deps
	$(TEST_BIN_BUILD)

test-web: web-deps chromium nats test-bin
	cd web && npm test
	cd web && SOFTHAPTIC_BIN=$(TEST_BIN_DIR)/softhaptic SOFTHAPTIC_HD_STANDIN="$$($(TEST_BIN_DIR)/hd-standin-path)" npm run test:e2e

# The Debian package, from one command: the binary, then the manual pages and completions it
# writes, then cargo-deb (installed from crates.io when missing) with server/Cargo.toml's
# [package.metadata.deb]. The .deb's path is the last line cargo-deb prints.
package: rust-tools web-deps cargo-deb
	$(PACKAGE_COMPILE)
	rm -rf $(PACKAGE_GEN) && mkdir -p $(PACKAGE_GEN)
	$(PACKAGE_BUILD)/softhaptic manpages --out $(PACKAGE_GEN)/man
	gzip -9n $(PACKAGE_GEN)/man/*.1
	$(PACKAGE_BUILD)/softhaptic completions bash > $(PACKAGE_GEN)/softhaptic.bash
	$(PACKAGE_BUILD)/softhaptic completions zsh > $(PACKAGE_GEN)/_softhaptic
	$(PACKAGE_BUILD)/softhaptic completions fish > $(PACKAGE_GEN)/softhaptic.fish
	$(CARGO) deb -p softhaptic-server --no-build --profile $(PACKAGE_PROFILE) $(PACKAGE_DEB_FLAGS) --output $(TARGET_DIR)/debian/

# cargo-deb's debug build: its own dev profile optimises its compression (lzma-sys, xz2, zopfli),
# so it packages no slower and makes the same .deb byte for byte, and it compiles in about 1 min
# 10 s on two cores where its release build takes about 2 min.
cargo-deb:
	@command -v cargo-deb >/dev/null 2>&1 || $(CARGO) install cargo-deb --locked --debug

# The package as an operator gets it: unpacked and run with no source tree in reach, its units
# checked by systemd, its file list held to docs/install.md (web/tests/package.test.mjs).
test-package: chromium test-bin
	$(MAKE) package PACKAGE_PROFILE=dev PACKAGE_DEB_FLAGS= PACKAGE_COMPILE="$(TEST_BIN_BUILD)"
	cd web && SOFTHAPTIC_DEB="$(abspath $(TARGET_DIR))/debian/$$(cd $(abspath $(TARGET_DIR))/debian && ls -t softhaptic_*.deb | head -1)" npm run test:package

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

# A local teaching lab as docs/lab.md tells a lab to run one: nats-server with JetStream, TLS and
# the permissions `softhaptic nats-config` writes, two simulated stations (the liver pressed by a
# sphere and by a cone) and a hub, each signed in with its own nkey and trusting the lab's CA
# alone; Ctrl-C stops them all. Kept in target/lab across runs: the JetStream store (the
# archive), each station's recordings (archived by the station when it stops and, for earlier
# ones, when it starts), the NATS sign-in (nats-auth/: the seeds, mode 0600, and
# authorization.conf) and the lab's CA with NATS's certificate for 127.0.0.1 (tls/, made with
# openssl; the keys mode 0600). desk-1 starts with the shipped sphere-press session so that the
# hub has an archived session to replay from the first run. NATS is started in a session of its
# own, so that Ctrl-C reaches the stations first and they archive their sessions before it is
# stopped. `make lab LAB_PROFILE=dev` runs a debug build (no release build to wait for).
# nats-server logs "TLS handshake error: EOF" once at start: the probe below that waits for it to
# listen opens a connection and closes it.
lab: rust-tools web-deps nats
	$(CARGO) build --profile $(LAB_PROFILE) -p softhaptic-server --bin softhaptic
	@dir=$(abspath $(TARGET_DIR))/lab; bin=$(abspath $(LAB_BUILD))/softhaptic; nats=$$(command -v nats-server || echo /usr/sbin/nats-server); \
	command -v openssl >/dev/null 2>&1 || { echo "make lab: openssl makes the lab's CA: apt-get install openssl" >&2; exit 1; }; \
	mkdir -p "$$dir/nats" "$$dir/desk-1" "$$dir/desk-2"; \
	ls "$$dir"/desk-1/*.mcap >/dev/null 2>&1 || cp tests/sessions/sphere-press.mcap "$$dir/desk-1/"; \
	"$$bin" nats-config --station desk-1 --station desk-2 --out "$$dir/nats-auth" >/dev/null || exit 1; \
	tls="$$dir/tls"; \
	if [ ! -s "$$tls/ca.pem" ] || [ ! -s "$$tls/server.pem" ]; then \
	  echo "make lab: making the lab's CA and NATS's certificate in $$tls"; \
	  rm -rf "$$tls" && (umask 077 && mkdir -p "$$tls") && \
	  printf 'basicConstraints=critical,CA:FALSE\nkeyUsage=critical,digitalSignature\nextendedKeyUsage=serverAuth\nsubjectAltName=IP:127.0.0.1,DNS:localhost\n' > "$$tls/server.ext" && \
	  (umask 077 && openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 825 \
	    -subj "/CN=softhaptic make lab CA" -addext "basicConstraints=critical,CA:TRUE" \
	    -addext "keyUsage=critical,keyCertSign,cRLSign" -keyout "$$tls/ca-key.pem" -out "$$tls/ca.pem" && \
	  openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -subj "/CN=localhost" \
	    -keyout "$$tls/server-key.pem" -out "$$tls/server.csr" && \
	  openssl x509 -req -in "$$tls/server.csr" -CA "$$tls/ca.pem" -CAkey "$$tls/ca-key.pem" \
	    -CAcreateserial -days 825 -extfile "$$tls/server.ext" -out "$$tls/server.pem") 2>/dev/null \
	  || { echo "make lab: openssl could not make the lab's CA in $$tls" >&2; rm -rf "$$tls"; exit 1; }; \
	fi; \
	printf '# make lab: NATS with TLS and the lab'"'"'s permissions (docs/lab.md)\ntls {\n  cert_file: "%s"\n  key_file: "%s"\n}\ninclude "nats-auth/authorization.conf"\n' \
	  "$$tls/server.pem" "$$tls/server-key.pem" > "$$dir/nats.conf"; \
	setsid "$$nats" -c "$$dir/nats.conf" -a 127.0.0.1 -p $(LAB_NATS_PORT) -js -sd "$$dir/nats" & natspid=$$!; pids=; \
	trap 'kill $$pids 2>/dev/null; wait $$pids 2>/dev/null; kill $$natspid 2>/dev/null' EXIT; \
	trap 'exit 130' INT TERM; \
	tries=0; until bash -c 'exec 3<>/dev/tcp/127.0.0.1/$(LAB_NATS_PORT)' 2>/dev/null; do \
	  kill -0 $$natspid 2>/dev/null || { echo "make lab: nats-server stopped before it listened on 127.0.0.1:$(LAB_NATS_PORT) (port taken? set LAB_NATS_PORT)" >&2; exit 1; }; \
	  tries=$$((tries + 1)); [ $$tries -le 100 ] || { echo "make lab: nats-server did not listen on 127.0.0.1:$(LAB_NATS_PORT) within 10 s" >&2; exit 1; }; \
	  sleep 0.1; \
	done; \
	kill -0 $$natspid 2>/dev/null || { echo "make lab: nats-server stopped: is 127.0.0.1:$(LAB_NATS_PORT) another server's? (set LAB_NATS_PORT)" >&2; exit 1; }; \
	natsurl=nats://127.0.0.1:$(LAB_NATS_PORT); auth="$$dir/nats-auth"; \
	set -- $(LAB_PORTS); \
	"$$bin" --record-dir "$$dir/desk-1" --addr 127.0.0.1:$$1 --station desk-1 --nats $$natsurl \
	  --nats-credentials "$$auth/station-desk-1.nk" --nats-ca "$$tls/ca.pem" & pids="$$pids $$!"; \
	"$$bin" --record-dir "$$dir/desk-2" --addr 127.0.0.1:$$2 --station desk-2 --nats $$natsurl --scene scenes/cone.toml \
	  --nats-credentials "$$auth/station-desk-2.nk" --nats-ca "$$tls/ca.pem" & pids="$$pids $$!"; \
	"$$bin" hub --addr 127.0.0.1:$(LAB_HUB_PORT) --nats $$natsurl \
	  --nats-credentials "$$auth/hub.nk" --nats-ca "$$tls/ca.pem" & pids="$$pids $$!"; \
	wait
