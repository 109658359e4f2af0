"""``python -m app.cli``: the ``cellcal`` command line."""

import sys

from app.cli.commands import main

sys.exit(main())
