import os

# Tests run several solver processes side by side on 2 cores; keep MKL to one thread each.
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
