"""``python3 -m casest ...`` is the ``casest`` command (see :mod:`casest.apps.cli`)."""

import sys

from .apps.cli import main


sys.exit(main())
