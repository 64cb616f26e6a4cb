"""``python -m experiments.cli ARGS``: the ``clm-sim`` command from a checkout."""

import sys

from experiments.cli import main

sys.exit(main())
