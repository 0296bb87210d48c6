#!/usr/bin/env python3
"""Prints the tests CTest skipped and why, from its JUnit file (`ctest --output-junit FILE`).

CTest's summary counts a skipped test among neither the passed nor the failed ones and lists it
under "The following tests did not run" without its reason; this names the reason, e.g. the
missing data a test looked for (data/README.md). `make test` and scripts/check_standalone.sh
call it after ctest.

    python3 scripts/ctest_skips.py build/ctest.xml
"""
import os
import sys
import xml.etree.ElementTree as ET

# Lines of a test's output that say why it skipped: gtest's GTEST_SKIP message follows a line
# ending in ": Skipped"; scripts print "SKIP: ...".
def reason(case):
    out = (case.findtext("system-out") or "").splitlines()
    for i, line in enumerate(out):
        if line.rstrip().endswith(": Skipped") and i + 1 < len(out):
            return out[i + 1].strip()
        if line.startswith("SKIP: "):
            return line[len("SKIP: "):].strip()
    skipped = case.find("skipped")
    return skipped.get("message", "") if skipped is not None else ""


def main():
    if not os.path.exists(sys.argv[1]):
        return 0  # ctest stopped before writing it; its own output says why
    root = ET.parse(sys.argv[1]).getroot()
    cases = root.iter("testcase")
    skipped = [(c.get("name"), reason(c)) for c in cases if c.get("status") == "notrun"]
    total = int(root.get("tests", "0"))
    print(f"{len(skipped)} of {total} tests skipped (neither passed nor failed):")
    for name, why in skipped:
        print(f"  {name}: {why}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
