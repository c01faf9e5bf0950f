#!/usr/bin/env bash
# Keep the archived runs off the device machine: a device command carries the working tree (tracked and
# untracked-not-ignored files) plus .whl/, 64 MiB in all, and the report and results archives and the humanoid run
# folders (best checkpoints) are each about that large or larger. None of them is read there.
#
#   bash benchmarks/gpu/aside.sh on       # before the device calls: the archives leave git's index, and
#                                         # .git/info/exclude ignores them; the files stay where they are
#   bash benchmarks/gpu/aside.sh off      # after them: the index and the exclude file are as before
#   bash benchmarks/gpu/aside.sh size     # MiB that would travel now, .whl/ included; fails over 64
#
# Nothing on disk is moved or changed, and no commit is made; `off` must run before the next commit, or the commit
# would delete the archives. While `on`, a pre-commit hook refuses every commit (git commit --no-verify passes it).
set -euo pipefail
cd "$(dirname "$0")/../.."
ARCHIVES=(benchmarks/reports benchmarks/results benchmarks/gpu/humanoid_cpu)
exclude=.git/info/exclude
BEGIN="# from benchmarks/gpu/aside.sh on"
END="# to here"
hook=$(git rev-parse --git-path hooks)/pre-commit

travelling_bytes() {
    { git ls-files -z --cached --others --exclude-standard; if [ -d .whl ]; then find .whl -type f -print0; fi; } |
        du -cb --files0-from=- 2>/dev/null | tail -1 | cut -f1
}

case "${1:-}" in
on)
    if ! grep -qxF "$BEGIN" "$exclude" 2>/dev/null; then
        { echo "$BEGIN"; printf '/%s/\n' "${ARCHIVES[@]}"; echo "$END"; } >>"$exclude"
    fi
    git rm -r -q --cached --ignore-unmatch "${ARCHIVES[@]}"
    if [ -e "$hook" ] && ! grep -qF "$BEGIN" "$hook"; then
        echo "aside.sh: $hook exists, so no guard was added: run 'aside.sh off' before any commit" >&2
    else
        mkdir -p "$(dirname "$hook")"
        printf '#!/bin/sh\n%s\necho "aside.sh is on: the archives are out of the index; run bash benchmarks/gpu/aside.sh off first" >&2\nexit 1\n' \
            "$BEGIN" >"$hook"
        chmod +x "$hook"
    fi
    ;;
off)
    git reset -q -- "${ARCHIVES[@]}"
    if [ -f "$exclude" ]; then sed -i "\|^$BEGIN\$|,\|^$END\$|d" "$exclude"; fi
    if [ -f "$hook" ] && grep -qF "$BEGIN" "$hook"; then rm -f "$hook"; fi
    ;;
size) ;;
*)
    echo "usage: bash benchmarks/gpu/aside.sh on|off|size" >&2
    exit 2
    ;;
esac
bytes=$(travelling_bytes)
echo "would travel: $((bytes >> 20)) MiB of 64"
if [ "$1" = size ] && [ "$bytes" -gt $((64 * 1024 * 1024)) ]; then
    echo "aside.sh: over the 64 MiB a device command carries; run 'bash benchmarks/gpu/aside.sh on' before the device calls" >&2
    exit 1
fi
