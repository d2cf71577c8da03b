import sys

import bench
from studies._cli import dispatch


def main() -> int:
    """`python -m bench` / `deform-bench`."""
    return dispatch(bench)


if __name__ == "__main__":
    sys.exit(main())
