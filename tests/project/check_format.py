#!/usr/bin/env python3
"""Checks that the C++ sources are formatted as .clang-format says (clang-format --dry-run).

Usage: check_format.py CLANG_FORMAT ROOT; exit 1 naming every file clang-format would change.
To fix them: clang-format -i on the files named (scripts/format.sh does every file).
"""
import os
import subprocess
import sys

DIRS = ["host", "tests", "bench", "examples"]
SUFFIXES = {".cpp", ".hpp", ".inl", ".h"}
SKIP_DIRS = {"corpus", "regressions", "data", "results"}


def sources(root):
    for top in DIRS:
        for dirpath, dirnames, filenames in os.walk(os.path.join(root, top)):
            dirnames[:] = sorted(d for d in dirnames if d not in SKIP_DIRS)
            for name in sorted(filenames):
                if os.path.splitext(name)[1] in SUFFIXES:
                    yield os.path.join(dirpath, name)


def main():
    clang_format, root = sys.argv[1], sys.argv[2]
    files = list(sources(root))
    unformatted = []
    for path in files:
        out = subprocess.run([clang_format, "--dry-run", "--Werror", "--style=file", path], capture_output=True,
                             text=True, cwd=root)
        if out.returncode != 0:
            unformatted.append(os.path.relpath(path, root))
    for path in unformatted:
        print(f"{path}: not formatted as .clang-format says (run scripts/format.sh)")
    print(f"check_format: {len(files)} files, {len(unformatted)} not formatted")
    return 1 if unformatted else 0


if __name__ == "__main__":
    sys.exit(main())
