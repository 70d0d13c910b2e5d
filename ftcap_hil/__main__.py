"""``python -m ftcap_hil``: the ``ftcap-hil`` command line."""

import sys

from ftcap_hil.apps.cli import main

sys.exit(main())
