import sys

import studies
from studies._cli import dispatch

sys.exit(dispatch(studies))
