"""``python -m bayestouch …``: the command line, as the ``bayestouch`` script."""

import sys

from bayestouch.cli import main

if __name__ == "__main__":
    sys.exit(main())
