#!/bin/sh
# Makes headless Chromium available for the browser tests (tests/test_viewer_browser.py).
# Prints the browser's path and exits 0 when one is there (or was installed: Debian's `chromium`,
# as root); exits 1 with the reason on stderr when none can be had. With --no-install it only looks.
set -u
for candidate in "${CHROMIUM:-}" /usr/bin/chromium /usr/bin/chromium-browser; do
    if [ -n "$candidate" ] && [ -x "$candidate" ]; then
        echo "$candidate"
        exit 0
    fi
done
if [ "${1:-}" = "--no-install" ]; then
    echo "no chromium at /usr/bin/chromium (and --no-install)" >&2
    exit 1
fi
if [ "$(id -u)" != "0" ]; then
    echo "no chromium at /usr/bin/chromium and not root: cannot apt-get install it" >&2
    exit 1
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "no chromium at /usr/bin/chromium and no apt-get to install it" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
if ! apt-get install -y --no-install-recommends chromium >&2; then
    apt-get update >&2 && apt-get install -y --no-install-recommends chromium >&2 || {
        echo "apt-get install chromium failed" >&2
        exit 1
    }
fi
if [ -x /usr/bin/chromium ]; then
    echo /usr/bin/chromium
    exit 0
fi
echo "apt-get installed chromium but /usr/bin/chromium is missing" >&2
exit 1
