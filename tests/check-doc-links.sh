#!/usr/bin/env bash
# Checks that every relative link in the repository's Markdown files resolves: the file (or
# directory) exists, and a `#anchor` names a heading of the target page (GitHub's slug rules:
# lower case, punctuation dropped, spaces to hyphens). External links (http, https, mailto) are
# not fetched. Exits non-zero and lists each broken link.
#
#   bash tests/check-doc-links.sh
set -euo pipefail
cd "$(dirname "$0")/.."
python3 - <<'PY'
import os, re, subprocess, sys

files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "*.md"],
                       capture_output=True, text=True, check=True).stdout.split()
files = [f for f in files if os.path.exists(f) and not f.startswith("target/")]

def slug(heading):
    s = heading.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")

def anchors(path):
    out, seen, fence = set(), {}, False
    for line in open(path, encoding="utf-8"):
        if line.startswith("```"):
            fence = not fence
        if fence:
            continue
        m = re.match(r"#{1,6}\s+(.*)", line)
        if m:
            base = slug(m.group(1))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out

link = re.compile(r"\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
bad = 0
for f in files:
    fence = False
    for no, line in enumerate(open(f, encoding="utf-8"), 1):
        if line.lstrip().startswith("```"):
            fence = not fence
        if fence:
            continue
        line = re.sub(r"`[^`]*`", "", line)
        for target in link.findall(line):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, anchor = target.partition("#")
            dest = os.path.normpath(os.path.join(os.path.dirname(f), path)) if path else f
            if not os.path.exists(dest):
                print(f"{f}:{no}: {target}: no such file {dest}")
                bad += 1
            elif anchor and dest.endswith(".md") and anchor not in anchors(dest):
                print(f"{f}:{no}: {target}: no heading '#{anchor}' in {dest}")
                bad += 1
print(f"{len(files)} Markdown files checked, {bad} broken links", file=sys.stderr)
sys.exit(1 if bad else 0)
PY
