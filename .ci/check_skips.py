"""Fail when pytest skipped a test for a reason not listed as a platform reason.

Usage: python .ci/check_skips.py REPORT.xml ALLOWED.txt

REPORT.xml is pytest's --junitxml output; ALLOWED.txt holds one regular
expression per line (``#`` starts a comment) for the skip reasons CI accepts.
"""

import re
import sys
import xml.etree.ElementTree as ElementTree


def main(report_path, allowed_path):
    allowed = [re.compile(line.strip()) for line in open(allowed_path, encoding="utf-8")
               if line.strip() and not line.lstrip().startswith("#")]
    unexpected = []
    skipped = 0
    for case in ElementTree.parse(report_path).iter("testcase"):
        for skip in case.findall("skipped"):
            if skip.get("type") == "pytest.xfail":  # an expected failure, not a skip
                continue
            skipped += 1
            reason = skip.get("message", "")
            if not any(pattern.search(reason) for pattern in allowed):
                unexpected.append(f"{case.get('classname')}::{case.get('name')}: {reason}")
    if unexpected:
        print(f"ci: {len(unexpected)} test(s) skipped for a reason that is not a listed "
              "platform reason (.ci/allowed_skips.txt):")
        for line in unexpected:
            print(f"  {line}")
        return 1
    print(f"ci: {skipped} skipped, all for listed platform reasons")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
