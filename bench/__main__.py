import sys

import bench
from studies._cli import dispatch

sys.exit(dispatch(bench))
