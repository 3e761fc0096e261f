"""``python -m benchmarks [module ...]``: run the benchmarks and write ``benchmarks/results/``."""

import sys

from benchmarks.harness import run

if __name__ == "__main__":
    run(sys.argv[1:] or None)
