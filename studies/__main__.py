import sys

import studies
from studies._cli import dispatch


def main() -> int:
    """`python -m studies` / `deform-studies`."""
    return dispatch(studies)


if __name__ == "__main__":
    sys.exit(main())
