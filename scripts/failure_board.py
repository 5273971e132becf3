"""Regenerate leaderboards/failures/ (the failure board: cross-table, failure suites, failure maps).

    python scripts/failure_board.py [--jobs 2] [--out leaderboards/failures]

The same as `overtakezoo failure-board`; see benchmark/failures/board.py and docs/failures.md.
"""

import sys

from overtakezoo.benchmark.cli import main

if __name__ == "__main__":
    sys.exit(main(["failure-board", *sys.argv[1:]]))
