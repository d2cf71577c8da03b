"""`python -m tests.service.golden [--write]`: compare the service's replies with replies.json, or record them anew."""

import argparse
import sys

from . import COMMAND, FIXTURE, VARIANTS, differences, environment, is_numeric, load, replay, served, write


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tests.service.golden", description=__doc__)
    ap.add_argument("--write", action="store_true", help=f"record {FIXTURE.name} anew (run from the repository root)")
    args = ap.parse_args(argv)
    if args.write:
        golden = write()
        print(f"wrote {len(golden['cases'])} replies to {FIXTURE}")
        return 0
    golden, here, failed, skipped = load(), environment(), 0, 0
    for variant in VARIANTS:
        with served(variant) as client:
            for case in golden["cases"]:
                if differences(golden["environment"], here, numeric=is_numeric(case)):
                    skipped += 1
                    continue
                if replay(client, case["request"]) != case["reply"]:
                    failed += 1
                    print(f"{variant}: {case['request']['name']}: the reply differs")
    print(f"{failed} replies differ, {skipped} not compared (another environment); rewrite with: {COMMAND}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
