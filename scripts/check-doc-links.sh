#!/usr/bin/env bash
# Checks the relative links of README.md and docs/**/*.md: every target must exist in the
# repository (and not be a git-ignored path such as .cache/, which is never committed),
# every image must be a file, a page of the book (docs/) may only link inside docs/ (mdBook
# copies nothing else into the rendered book), every #anchor must name a heading of its page (GitHub's and
# mdBook's ids: lower case, punctuation dropped, spaces to hyphens, -1, -2 for repeats), and
# docs/SUMMARY.md must list every page of the book. Links inside code blocks and code
# spans are not links. External links (http:, https:, mailto:, ...) are not fetched.
# Exits 1 naming each broken link as FILE:LINE; bash and python3 only, no packages.
set -euo pipefail
cd "$(dirname "$0")/.."
exec python3 - "$@" <<'PY'
import os
import re
import subprocess
import sys

ROOT = os.getcwd()


def pages():
    out = ["README.md"] if os.path.exists("README.md") else []
    for d, _, files in os.walk("docs"):
        out += [os.path.join(d, f) for f in sorted(files) if f.endswith(".md")]
    return sorted(set(out))


def blank_fences(text):
    """Fenced code blocks replaced by empty lines (so line numbers still count)."""
    lines, fence = [], None
    for line in text.split("\n"):
        m = re.match(r"^ {0,3}(`{3,}|~{3,})", line)
        if fence is None and m:
            fence = m.group(1)[0] * len(m.group(1))
            lines.append("")
        elif fence is not None:
            if line.strip().startswith(fence) and line.strip().strip(fence[0]) == "":
                fence = None
            lines.append("")
        else:
            lines.append(line)
    return "\n".join(lines)


def blank_code(text):
    """Code blocks and code spans replaced by spaces (newlines kept, so lines still count)."""
    text = blank_fences(text)
    return re.sub(r"(`+)(.+?)\1", lambda m: re.sub(r"[^\n]", " ", m.group(0)), text, flags=re.S)


def slug(heading):
    s = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # links: their text
    s = re.sub(r"<[^>]+>", "", s)  # html tags
    s = s.replace("`", "").replace("*", "")
    s = s.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


_anchor_cache = {}


def anchors(path):
    if path not in _anchor_cache:
        text = open(path, encoding="utf-8").read()
        found, seen = set(), {}
        for line in blank_fences(text).split("\n"):
            m = re.match(r"^ {0,3}#{1,6}\s+(.*?)\s*#*\s*$", line)
            if m:
                base = slug(m.group(1))
                n = seen.get(base, 0)
                seen[base] = n + 1
                found.add(base if n == 0 else f"{base}-{n}")
            for a in re.findall(r"""<a\s+(?:id|name)=["']([^"']+)["']""", line):
                found.add(a)
            for a in re.findall(r"\{#([\w-]+)\}", line):
                found.add(a)
        _anchor_cache[path] = found
    return _anchor_cache[path]


def ignored(rel):
    try:
        r = subprocess.run(["git", "check-ignore", "-q", rel], cwd=ROOT,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        return r.returncode == 0
    except FileNotFoundError:
        return False


LINK = re.compile(r"(!?)\[((?:[^\[\]]|\[[^\]]*\])*)\]\(\s*(<[^>]*>|[^)\s]+)(?:\s+(?:\"[^\"]*\"|'[^']*'))?\s*\)")
REFDEF = re.compile(r"^ {0,3}\[[^\]]+\]:\s*(<[^>]*>|\S+)", re.M)

errors = []
checked = 0
for page in pages():
    text = open(page, encoding="utf-8").read()
    body = blank_code(text)
    targets = []
    for m in LINK.finditer(body):
        targets.append((body.count("\n", 0, m.start()) + 1, m.group(1) == "!", m.group(3)))
    for m in REFDEF.finditer(body):
        targets.append((body.count("\n", 0, m.start()) + 1, False, m.group(1)))
    for line, image, target in targets:
        target = target.strip("<>")
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith("//"):
            continue  # external: http:, https:, mailto:, file: ...
        checked += 1
        where = f"{page}:{line}: ({target})"
        path, _, anchor = target.partition("#")
        path = path.split("?")[0]
        if path == "":
            dest = page
        else:
            if path.startswith("/"):
                errors.append(f"{where} absolute path; use a relative one")
                continue
            dest = os.path.normpath(os.path.join(os.path.dirname(page), path))
            if dest.startswith(".."):
                errors.append(f"{where} leaves the repository")
                continue
            if page.startswith("docs" + os.sep) and not dest.startswith("docs" + os.sep):
                # mdBook copies only docs/ into the book: such a link is broken there.
                errors.append(f"{where} leaves the book (docs/): move the file into docs/ or name it as code")
                continue
            if not os.path.exists(dest):
                errors.append(f"{where} {dest} does not exist")
                continue
            if ignored(dest):
                errors.append(f"{where} {dest} is ignored by git (never committed)")
                continue
            if image and not os.path.isfile(dest):
                errors.append(f"{where} image {dest} is not a file")
                continue
        if anchor:
            if not dest.endswith(".md"):
                errors.append(f"{where} an anchor into a file that is not markdown")
            elif anchor not in anchors(dest):
                errors.append(f"{where} no heading #{anchor} in {dest}")

# docs/SUMMARY.md lists every page of the book.
summary = "docs/SUMMARY.md"
if os.path.exists(summary):
    listed = set()
    for m in LINK.finditer(blank_code(open(summary, encoding="utf-8").read())):
        listed.add(os.path.normpath(os.path.join("docs", m.group(3).strip("<>").split("#")[0])))
    for page in pages():
        if page.startswith("docs" + os.sep) and page != summary and page not in listed:
            errors.append(f"{summary}: does not list {page}")

for e in errors:
    print(e)
n_pages = len(pages())
if errors:
    print(f"check-doc-links: {len(errors)} broken of {checked} relative links in {n_pages} pages")
    sys.exit(1)
print(f"check-doc-links: {checked} relative links in {n_pages} pages, all resolve")
PY
