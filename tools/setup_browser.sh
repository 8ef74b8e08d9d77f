#!/usr/bin/env bash
# Install the headless browser the dashboard tests drive: Debian's `chromium` and
# `chromium-driver` (apt-get). The Python side (selenium) comes from pyproject.toml's `dev`
# extra and is pointed at these two programs; nothing downloads a browser of its own.
# Idempotent: does nothing when both programs are already there.
#
#   bash tools/setup_browser.sh        (what `make setup-browser` runs; root or sudo needed)
#
# Without apt-get (not Debian/Ubuntu) it says what to install and exits 0, so `make setup`
# still finishes: the browser tests then skip and say why.
set -euo pipefail

say() { printf '[setup-browser] %s\n' "$*"; }
die() { printf '[setup-browser] ERROR: %s\n' "$*" >&2; exit 1; }

have() {
  command -v "$1" >/dev/null 2>&1
}

browser() {
  for b in chromium chromium-browser; do
    if have "$b"; then command -v "$b"; return 0; fi
  done
  return 1
}

if browser >/dev/null && have chromedriver; then
  say "chromium and chromedriver already installed: $(browser), $(command -v chromedriver)"
  exit 0
fi

if ! have apt-get; then
  say "apt-get is not available on this machine: install Chromium and its matching chromedriver"
  say "with your package manager (Debian: apt-get install chromium chromium-driver) and put both"
  say "on PATH, or set FLEET_CHROMIUM and FLEET_CHROMEDRIVER. The browser tests skip until then."
  exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  have sudo || die "installing chromium needs root: run as root or install sudo"
  SUDO="sudo"
fi

say "installing chromium and chromium-driver with apt-get (about 300 MB)"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q >/dev/null || die "apt-get update failed (no access to the Debian archive?)"
$SUDO apt-get install -y -q --no-install-recommends chromium chromium-driver fonts-dejavu-core >/dev/null \
  || die "apt-get install chromium chromium-driver failed"
browser >/dev/null || die "chromium was installed but is not on PATH"
have chromedriver || die "chromium-driver was installed but chromedriver is not on PATH"
say "installed: $("$(browser)" --version 2>/dev/null | head -1), $(chromedriver --version | head -1)"
