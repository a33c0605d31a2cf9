#!/usr/bin/env bash
# Open the book that `lsmta reproduce` built (build/book/index.html, or DIR/book/index.html
# for `bash scripts/open_book.sh DIR`) in the reader's browser. It opens from the file
# system, with no server and no network. On a machine with no display it prints the path
# (and the file:// address) to open elsewhere.
set -euo pipefail
cd "$(dirname "$0")/.."
build="${1:-build}"
index="$build/book/index.html"
if [ ! -f "$index" ]; then
  echo "open_book: no $index; run 'bash scripts/reproduce.sh' (or 'lsmta book') first" >&2
  exit 1
fi
path="$(cd "$(dirname "$index")" && pwd)/index.html"
if [ -n "${DISPLAY:-}${WAYLAND_DISPLAY:-}" ] || [ "$(uname)" = Darwin ]; then
  for opener in xdg-open open chromium firefox; do
    if command -v "$opener" >/dev/null 2>&1; then
      "$opener" "$path" >/dev/null 2>&1 &
      echo "opened $path"
      exit 0
    fi
  done
fi
echo "the book: $path"
echo "open file://$path in a browser (no server needed)"
