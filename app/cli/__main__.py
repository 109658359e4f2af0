"""``python -m app.cli``: the ``cellcal`` command line."""

import sys

from app.cli.main import main

sys.exit(main())
