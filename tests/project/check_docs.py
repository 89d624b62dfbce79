#!/usr/bin/env python3
"""Checks that the documents agree with the code and speak of the software alone.

- docs/cli.md names every option `cullpipe <command> --help` prints, and no option that none
  prints; bench/README.md likewise for the benchmark programs.
- README.md is at most 300 lines, and every relative link in README.md, docs/ and bench/*.md
  points at a file that exists.
- No project file speaks of how the work was organised (PROCESS_WORDS below), only of the
  software.

Usage: check_docs.py ROOT CULLPIPE_EXE [BENCH_EXE ...]; exit 1 with every problem listed.
"""
import os
import re
import subprocess
import sys

OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def help_options(exe, args):
    out = subprocess.run([exe, *args, "--help"], capture_output=True, text=True, timeout=60)
    if out.returncode != 0:
        raise SystemExit(f"{exe} {' '.join(args)} --help exited {out.returncode}: {out.stderr}")
    text = out.stdout
    # CLI11 lists a command's subcommands after "Subcommands:"; their names are not options.
    sub = re.findall(r"^Subcommands:\n((?:  \S.*\n)+)", text, re.M)
    names = [line.split()[0] for block in sub for line in block.splitlines()]
    return set(OPTION.findall(text)) - {"--help"}, names


def doc_options(path):
    with open(path, encoding="utf-8") as f:
        text = f.read()
    # Options as the document writes them: inside `code` spans and fenced blocks.
    code = re.findall(r"`([^`\n]+)`", text) + re.findall(r"```[^\n]*\n(.*?)```", text, re.S)
    lines = [line for block in code for line in block.splitlines()]
    # Other programs' options (cmake --install, ctest --output-on-failure) are not the tool's.
    ours = [line for line in lines if not re.match(r"\s*(sudo |\$ )?(cmake|ctest|apt-get|git|gdb|perf)\b", line)]
    return set(OPTION.findall("\n".join(ours))) - {"--help"}


def compare(doc, documented, printed, what, problems):
    for opt in sorted(printed - documented):
        problems.append(f"{doc}: {opt} ({what} --help prints it) is not documented")
    for opt in sorted(documented - printed):
        problems.append(f"{doc}: {opt} is documented but no {what} --help prints it")


# Words about how the work was organised: a working sitting, a second look at a change, a
# numbered tracker entry, a batch of work, a date. Spelled in pieces, so that no line here
# reads as one of them.
_SITTING, _LOOK, _ENTRY, _ROUND = "ses" "sions?", "re" "view(?:s|ed|er)?", "is" "sue", "ro" "und"
PROCESS_WORDS = re.compile(
    rf"\b(?:{_SITTING}|{_LOOK})\b|\b{_ENTRY} #?\d+|\b{_ROUND} (?:of|\d)|\bthis {_ROUND}\b|\b20\d\d-\d\d-\d\d\b",
    re.I)
# Source, build and document files; data (scenes, fuzz corpora, results) is not prose.
TEXT_SUFFIXES = {".cpp", ".hpp", ".inl", ".h", ".comp", ".glsl", ".vert", ".frag", ".md", ".txt", ".cmake", ".in",
                 ".sh", ".py", ".supp"}
SKIP_DIRS = {".git", "corpus", "regressions", "results", "data"}


def project_files(root):
    for top in ["CMakeLists.txt", "README.md", ".ci", "bench", "cmake", "docs", "examples", "host", "scripts",
                "shaders", "tests"]:
        path = os.path.abspath(os.path.join(root, top))
        if os.path.isfile(path):
            yield path
            continue
        for dirpath, dirnames, filenames in os.walk(path):
            dirnames[:] = [d for d in dirnames if d not in SKIP_DIRS and not d.startswith("build")]
            for name in filenames:
                if os.path.splitext(name)[1] in TEXT_SUFFIXES or name in ("CMakeLists.txt", "run"):
                    yield os.path.join(dirpath, name)


def main():
    root, cullpipe, benches = sys.argv[1], sys.argv[2], sys.argv[3:]
    problems = []

    top, commands = help_options(cullpipe, [])
    printed = set(top)
    for command in commands:
        printed |= help_options(cullpipe, [command])[0]
    compare("docs/cli.md", doc_options(os.path.join(root, "docs/cli.md")), printed, "cullpipe", problems)

    if benches:
        printed = set()
        for exe in benches:
            printed |= help_options(exe, [])[0]
        documented = {o for o in doc_options(os.path.join(root, "bench/README.md")) if not o.startswith("--benchmark")}
        # The benchmark document may show the tool's options where it runs the tool.
        tool = doc_options(os.path.join(root, "docs/cli.md"))
        compare("bench/README.md", documented - (tool - printed), printed, "benchmark program", problems)

    with open(os.path.join(root, "README.md"), encoding="utf-8") as f:
        lines = f.read().count("\n")
    if lines > 300:
        problems.append(f"README.md: {lines} lines; at most 300 (reference material goes to docs/)")

    docs = [os.path.join(root, "README.md")] + [os.path.join(root, d, n) for d in ("docs", "bench")
                                                 for n in sorted(os.listdir(os.path.join(root, d))) if n.endswith(".md")]
    for doc in docs:
        with open(doc, encoding="utf-8") as f:
            text = f.read()
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            if not os.path.exists(os.path.join(os.path.dirname(doc), target)):
                problems.append(f"{os.path.relpath(doc, root)}: link to {target}, which does not exist")

    for path in project_files(root):
        with open(path, encoding="utf-8", errors="replace") as f:
            for number, line in enumerate(f, 1):
                m = PROCESS_WORDS.search(line)
                if m:
                    problems.append(f"{os.path.relpath(path, root)}:{number}: '{m.group(0)}' speaks of how the work "
                                    f"was organised, not of the software")

    for p in problems:
        print(p)
    print(f"check_docs: {len(problems)} problem(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
