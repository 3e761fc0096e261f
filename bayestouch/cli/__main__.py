"""``python -m bayestouch.cli``: the ``bayestouch`` command."""

import sys

from bayestouch.cli.main import main

sys.exit(main())
