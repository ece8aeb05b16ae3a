"""``python -m arc_env.cli``: the ``arc-calib`` command."""

import sys

from arc_env.cli import main

sys.exit(main())
