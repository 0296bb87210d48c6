#!/usr/bin/env python3
"""Breaks the code on purpose, one small mutation at a time, and reports which ones no test caught.

Each mutation in scripts/mutations.json names a file, a piece of text that must occur there
exactly once, its replacement, and the CTest regex of the tests that should catch it. For each:
apply it, rebuild (a separate build tree, build-mutation/), run those tests, restore the file.
A mutation is *caught* when a selected test fails, *survived* when all pass, *invalid* when the
text is not found exactly once or the mutant does not compile (the list needs updating).

    scripts/mutation_check.sh [--only ID[,ID...]] [--out docs/testing.md]   (make mutation)
    MUTATION_BUILD=build scripts/mutation_check.sh   reuses an existing build tree (rebuilt after)
    MUTATION_TARGETS="terramap test_integration" ...  builds only those targets (a partial run)

Exit code: 0 when every mutation was caught, 1 otherwise. The working tree is restored even on
Ctrl-C (each file is written back from memory in a finally block).
"""
import argparse
import json
import os
import shutil
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUILD = os.environ.get("MUTATION_BUILD", os.path.join(ROOT, "build-mutation"))


def run(cmd, **kw):
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, **kw)


def configure():
    if os.path.exists(os.path.join(BUILD, "build.ninja")):
        return
    r = run(["cmake", "-S", ".", "-B", BUILD, "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
             # Python and the web view stay on: mutations of the bindings and of the live
             # view are caught by their tests (Python.Bindings, Web.LiveViewInHeadlessChromium).
             "-DTERRAMAP_BUILD_BENCHMARKS=OFF", "-DTERRAMAP_TEST_SANITIZED_HOST=OFF"] +
            # Every mutant is restored afterwards, so most of a rebuild is the same objects again.
            (["-DCMAKE_CXX_COMPILER_LAUNCHER=ccache"] if shutil.which("ccache") else []))
    if r.returncode:
        sys.exit("configuring build-mutation failed:\n" + r.stdout + r.stderr)


def build():
    # MUTATION_TARGETS (space-separated): build only what the selected mutations' tests need,
    # e.g. for a partial run (the whole tree is rebuilt otherwise, for every mutation).
    targets = os.environ.get("MUTATION_TARGETS", "").split()
    return run(["cmake", "--build", BUILD, "-j", os.environ.get("JOBS", "2")] +
               (["--target"] + targets if targets else []))


def tests(regex):
    return run(["ctest", "--test-dir", BUILD, "-R", regex, "-j", os.environ.get("JOBS", "2"), "--timeout", "600"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--list", default=os.path.join(ROOT, "scripts", "mutations.json"))
    ap.add_argument("--only", default="", help="comma-separated mutation ids")
    ap.add_argument("--out", default="", help="write the Markdown table here (between the markers)")
    args = ap.parse_args()
    mutations = json.load(open(args.list))
    if args.only:
        keep = set(args.only.split(","))
        mutations = [m for m in mutations if m["id"] in keep]
    configure()
    b = build()
    if b.returncode:
        sys.exit("the unmutated tree does not build:\n" + b.stdout[-3000:])
    rows, survived = [], 0
    for m in mutations:
        path = os.path.join(ROOT, m["file"])
        original = open(path).read()
        t0 = time.time()
        verdict, detail = "", ""
        try:
            if original.count(m["find"]) != 1:
                verdict, detail = "invalid", "text found %d times" % original.count(m["find"])
            else:
                open(path, "w").write(original.replace(m["find"], m["replace"]))
                b = build()
                if b.returncode:
                    verdict, detail = "invalid", "does not compile"
                else:
                    r = tests(m["tests"])
                    failed = [l.split(" - ")[1].split(" (")[0] for l in r.stdout.splitlines()
                              if " - " in l and ("(Failed)" in l or "(Timeout)" in l or "(SEGFAULT)" in l
                                                 or "(Subprocess aborted)" in l)]
                    if "No tests were found" in r.stdout + r.stderr:
                        verdict, detail = "invalid", "no test matches " + m["tests"]
                    elif failed:
                        verdict, detail = "caught", ", ".join(failed[:3]) + (" …" if len(failed) > 3 else "")
                    else:
                        verdict, detail = "SURVIVED", "every selected test passed"
        finally:
            open(path, "w").write(original)
        if verdict != "caught":
            survived += 1
        rows.append((m["id"], m["description"], m["file"], verdict, detail, time.time() - t0))
        print("%-28s %-9s %s (%.0f s)" % (m["id"], verdict, detail, rows[-1][-1]), flush=True)
    build()  # leave build-mutation matching the tree
    table = ["| mutation | what it breaks | file | verdict | caught by |", "| --- | --- | --- | --- | --- |"]
    for mid, desc, f, verdict, detail, _ in rows:
        table.append("| `%s` | %s | `%s` | %s | %s |" % (mid, desc, f, verdict, detail))
    text = "\n".join(table) + "\n"
    if args.out:
        doc = open(args.out).read()
        a, z = "<!-- mutation-table -->", "<!-- /mutation-table -->"
        i, j = doc.index(a) + len(a), doc.index(z)
        if args.only:
            # A partial run replaces its own rows and keeps the others (in the list's order).
            fresh = {line.split("`")[1]: line for line in table[2:]}
            old = {line.split("`")[1]: line for line in doc[i:j].strip().splitlines()[2:] if line.startswith("| `")}
            old.update(fresh)
            order = [m["id"] for m in json.load(open(args.list))]
            table = table[:2] + [old[mid] for mid in order if mid in old]
            text = "\n".join(table) + "\n"
        open(args.out, "w").write(doc[:i] + "\n" + text + doc[j:])
    print(text)
    return 1 if survived else 0


if __name__ == "__main__":
    sys.exit(main())
