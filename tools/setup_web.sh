#!/usr/bin/env bash
# Install what the light-map viewer and its browser test need: Debian's Chromium
# (/usr/bin/chromium) and the pinned npm packages of web/ (three, playwright-core,
# from web/package-lock.json). Idempotent: returns at once when both are there.
# Writes web/.pdic-web-ready, which tests/test_viewer_browser.py requires (the test
# fails loudly, naming this script, when set-up did not run).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
WEB="$ROOT/web"
STAMP="$WEB/.pdic-web-ready"
say() { echo "setup_web: $*" >&2; }

lock_hash() { sha256sum "$WEB/package-lock.json" | cut -d' ' -f1; }

if [[ -x /usr/bin/chromium && -d "$WEB/node_modules/three" && -d "$WEB/node_modules/playwright-core" \
      && -f "$STAMP" && "$(cat "$STAMP")" == "$(lock_hash)" ]]; then
    exit 0
fi

if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
    say "error: Node.js and npm are needed (apt-get install nodejs npm, Node >= 18)"
    exit 1
fi
if [[ ! -x /usr/bin/chromium ]]; then
    if [[ $(id -u) -ne 0 ]] && ! command -v sudo >/dev/null 2>&1; then
        say "error: /usr/bin/chromium is missing and installing it needs root (apt-get install chromium)"
        exit 1
    fi
    SUDO=""; [[ $(id -u) -ne 0 ]] && SUDO="sudo"
    say "installing Debian's chromium (apt-get)"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends chromium >/dev/null
fi
say "installing web/ packages (npm ci, pinned by package-lock.json)"
(cd "$WEB" && npm ci --no-audit --no-fund --loglevel=error)
lock_hash >"$STAMP"
say "ready: $(/usr/bin/chromium --version 2>/dev/null | head -1), three $(node -p "require('$WEB/node_modules/three/package.json').version")"
