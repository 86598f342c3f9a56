"""``python -m railwatch.cli``: the command line."""

import sys

from railwatch.cli.app import main

sys.exit(main())
