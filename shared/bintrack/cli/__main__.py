"""``python -m bintrack.cli``: the ``bintrack`` command."""

import sys

from bintrack.cli.main import main

sys.exit(main())
