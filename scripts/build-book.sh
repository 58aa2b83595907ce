#!/usr/bin/env bash
# Builds the book (docs/, mdBook) into target/book, after the link check
# (scripts/check-doc-links.sh: relative links, anchors, SUMMARY.md listing every page).
# Installs the pinned mdBook with cargo where it is missing (4 min 16 s on this 2-core VM beside another build, once;
# without its `serve` and `watch` features, which a build does not need). Idempotent.
# mdBook's warnings (a page missing from SUMMARY.md, a broken include) fail the build.
set -euo pipefail
cd "$(dirname "$0")/.."
MDBOOK_VERSION=0.5.4
if [ "$(mdbook --version 2>/dev/null)" != "mdbook v$MDBOOK_VERSION" ]; then
  echo "build-book.sh: cargo install mdbook --version $MDBOOK_VERSION --locked" >&2
  cargo install mdbook --version "$MDBOOK_VERSION" --locked --no-default-features --features search --quiet
fi
scripts/check-doc-links.sh
LOG=$(mktemp)
trap 'rm -f "$LOG"' EXIT
mdbook build docs 2>&1 | tee "$LOG"
if grep -Eq '(WARN|ERROR)' "$LOG"; then
  echo "build-book.sh: mdbook printed warnings or errors (above)" >&2
  exit 1
fi
echo "build-book.sh: the book is in target/book/index.html"
