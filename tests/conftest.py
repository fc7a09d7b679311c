import os

# llvmpipe spawns render threads per context; on a 2-core machine with several test processes that
# only adds contention (see the env benchmark for the measured choice).
os.environ.setdefault("LP_NUM_THREADS", "0")
